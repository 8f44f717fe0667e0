"""jaxpose: self-supervised 3D human pose lifting from multi-view geometry, in JAX/Flax.

Modules: `camera`, `triangulation`, `losses`, `metrics`, `model`, `train`, `checkpoint`,
`evaluation`, `viz`, `skeleton`, `keypoint_formats`, `inference`, and the `data` package.
"""

__version__ = "0.1.0"
