"""jaxpose: self-supervised 3D human pose lifting from multi-view geometry, in JAX/Flax.

Geometry and joints: `camera`, `triangulation`, `skeleton`, `layouts` (detector keypoint layouts),
`metrics`, `chunks`.  Packages, each importing only those before it: `formats` (the files users bring
and take away), `data` (the batch and the in-memory data set), `datasets` (Human3.6M, HumanEva-I,
MPI-INF-3DHP), `synthetic` (the simulator and the example rig project), `calibration` (a rig
recovered from the person), `rig` (a user's rig project).  Then the lifter and its losses (`model`,
`losses`, `robust`), `training` (the step, configs, checkpoints, evaluation, the run and its report),
`serving` (a trained lifter as a function, tracking, figures), `reconstruction` (multi-view 3D motion)
and the command lines (`predict`, `export`, `calibrate`, `reconstruct`).
"""

__version__ = "0.1.0"
