"""jaxpose: self-supervised 3D human pose lifting from multi-view geometry, in JAX/Flax.

Geometry and joints: `camera`, `triangulation`, `skeleton`, `layouts` (detector keypoint layouts),
`metrics`, `chunks`.  Packages, each importing only those before it: `formats` (the files users bring
and take away), `data` (the batch and the in-memory data set), `datasets` (Human3.6M, HumanEva-I,
MPI-INF-3DHP), `synthetic` (the simulator and the example rig project), `calibration` (a rig
recovered from the person), `rig` (a user's rig project).  Then training and evaluation (`model`,
`losses`, `train`, `config`, `checkpoint`, `evaluation`, `validation`, `pseudo_labelling`, `robust`),
inference and the command lines (`inference`, `predict`, `export`, `calibrate`).
"""

__version__ = "0.1.0"
