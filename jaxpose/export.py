"""Ship a trained lifter: a self-contained single-view model in ONNX and in JAX's serialized form.

    python -m jaxpose.export runs/synthetic --output lifter.onnx

writes, for the newest readable checkpoint of the run:

  lifter.onnx         ONNX (converted by jax2onnx; `pip install 'jaxpose[export]'`), runnable with
                      onnxruntime alone; the skeleton and its joint names are in its metadata
  lifter.jax_export   the same function serialized with `jax.export` (JAX only, no jaxpose needed:
                      `jax.export.deserialize(data).call(keypoints, K, confidence)`)
  lifter.json         the metadata of both: skeleton, joint names, inputs, output, units, step, and
                      test_time_flip: whether the flip (`--flip`, `jaxpose.flip`) is inside the graph

The model takes what `jaxpose.serving.inference.Lifter3D.predict` takes, for any number B of poses:

  keypoints   f32[B, J, 2]  undistorted pixels, in the skeleton's joint order
  K           f32[B, 3, 3]  the intrinsics of each pose's camera
  confidence  f32[B, J]     detector scores; a joint scored below the run's threshold (--min-confidence,
                            by default the one it was trained with) or 0 is missing, its coordinates ignored

and returns `pose3d_mm` f32[B, J, 3]: root-relative millimetres in each camera's frame (x right,
y down, z forward); rows whose root (joint 0) is missing are NaN.  A temporal lifter (window T > 1)
takes windows instead, keypoints f32[B, T, J, 2] and confidence f32[B, T, J] (T frames of one camera
centred on the frame to lift; repeat the first / last frame beyond a sequence's ends, as
`Lifter3D.predict` does), and returns the centre frame's pose; the window is in the metadata.  Distorted detections must be
undistorted first (`Lifter3D.predict(distortion=...)` does it; the exported model does not).

With --flip, both forms hold the test-time flip augmentation in their graph (the pose and its mirror image
in normalised camera coordinates lifted and averaged, `jaxpose.flip`): they compute
`Lifter3D.predict(..., flip=True)`, at twice the cost, and nothing is left for the user to do.

None of the three files is written over without --overwrite, nor a file of the run directory ever
(`jaxpose.formats.outputs`); each is written to a temporary name and renamed into place when complete.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pathlib
from collections.abc import Callable
from typing import Annotated, Any

import jax
import jax.numpy as jnp
import tyro

from jaxpose.training import checkpoint
from jaxpose.formats.outputs import OutputError, atomic_output, check_output
from jaxpose.serving.inference import DEFAULT_MIN_CONFIDENCE, Lifter3D, load, parse_with_run
from jaxpose.skeleton import ROOT

INPUT_NAMES = ("keypoints", "K", "confidence")
OUTPUT_NAME = "pose3d_mm"
JAX_SUFFIX = ".jax_export"


def single_view_function(
    lifter: Lifter3D, flip: bool = False, min_confidence: float = 0.0
) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
    """The lifter as one pure function (keypoints, K, confidence) -> pose3d_mm, its variables baked
    in: what `Lifter3D.predict(..., flip=flip, min_confidence=min_confidence)` computes for undistorted
    keypoints, missing joints and roots included (a joint scored below `min_confidence` is missing); with
    `flip` the mirror image's lift and the average are part of the function."""

    centre = lifter.model_config.temporal_window // 2
    eval_step = lifter.flipped_eval_step if flip else lifter.eval_step

    def lift(keypoints: jax.Array, K: jax.Array, confidence: jax.Array) -> jax.Array:
        detected = (confidence > 0) & (confidence >= min_confidence)
        confidence = jnp.where(detected, confidence, 0.0)
        keypoints = jnp.where(detected[..., None], keypoints, 0.0)  # NaN in a missing joint stays out
        poses = eval_step(lifter.variables, keypoints, K, confidence)
        root = detected[:, ROOT] if detected.ndim == 2 else detected[:, centre, ROOT]
        return jnp.where(root[:, None, None], poses, jnp.nan)

    return lift


def metadata(lifter: Lifter3D, flip: bool = False, min_confidence: float = 0.0) -> dict[str, Any]:
    """What a user of the exported model needs to know, without jaxpose."""
    J, T = lifter.num_joints, lifter.model_config.temporal_window
    frames = "" if T == 1 else f"{T}, "
    window = "" if T == 1 else f" of the {T} frames centred on the one lifted (the first / last frame repeated beyond a sequence's ends)"
    return {
        "skeleton": lifter.skeleton.name,
        "joint_names": list(lifter.joint_names),
        "temporal_window": T,
        "inputs": {
            "keypoints": f"f32[B, {frames}{J}, 2] undistorted pixels{window}, joints in joint_names order",
            "K": "f32[B, 3, 3] camera intrinsics",
            "confidence": f"f32[B, {frames}{J}] detector scores: a joint scored below min_confidence (or 0) is missing",
        },
        "min_confidence": min_confidence,
        "output": {OUTPUT_NAME: f"f32[B, {J}, 3] root-relative mm in the camera frame (x right, y down, z forward); NaN rows where the root is missing"},
        "test_time_flip": flip,
        "step": lifter.step,
        "model": dataclasses.asdict(lifter.model_config),
    }


def _input_shapes(lifter: Lifter3D, batch) -> list[jax.ShapeDtypeStruct]:
    keypoints = lifter.model_config.build(lifter.num_joints).input_shape(batch)
    return [
        jax.ShapeDtypeStruct(keypoints, jnp.float32),
        jax.ShapeDtypeStruct((batch, 3, 3), jnp.float32),
        jax.ShapeDtypeStruct(keypoints[:-1], jnp.float32),
    ]


def export_jax(lifter: Lifter3D, path: str | pathlib.Path, flip: bool = False, min_confidence: float = 0.0) -> pathlib.Path:
    """Write the `jax.export` serialization of `single_view_function`, for any batch size."""
    (batch,) = jax.export.symbolic_shape("B")
    exported = jax.export.export(jax.jit(single_view_function(lifter, flip, min_confidence)))(*_input_shapes(lifter, batch))
    path = pathlib.Path(path)
    with atomic_output(path) as temporary:
        temporary.write_bytes(exported.serialize())
    return path


def export_onnx(lifter: Lifter3D, path: str | pathlib.Path, flip: bool = False, min_confidence: float = 0.0) -> pathlib.Path:
    """Write `single_view_function` as an ONNX model with a dynamic batch axis and the metadata.

    Raises ImportError without the `export` extra (jax2onnx, onnx), and whatever jax2onnx raises for
    an operation it cannot convert (its message names the JAX primitive).
    """
    import onnx
    from jax2onnx import to_onnx

    # onnx_ir logs a warning for every shape constant it serializes without a declared type.
    logging.getLogger("onnx_ir.serde").setLevel(logging.ERROR)
    shapes = [("B", *s.shape[1:]) for s in _input_shapes(lifter, 1)]
    model = to_onnx(
        single_view_function(lifter, flip, min_confidence), shapes, model_name="jaxpose_lifter",
        input_names=list(INPUT_NAMES), output_names=[OUTPUT_NAME],
    )  # fmt: skip
    onnx.helper.set_model_props(model, {key: json.dumps(value) for key, value in metadata(lifter, flip, min_confidence).items()})
    path = pathlib.Path(path)
    with atomic_output(path) as temporary:
        onnx.save(model, temporary)
    return path


@dataclasses.dataclass(frozen=True)
class ExportArgs:
    """Export a trained lifter as ONNX and as a `jax.export` serialization, with a metadata JSON."""

    run_dir: tyro.conf.Positional[Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN_DIR")]]
    """Run directory (or its checkpoints/ folder); the newest readable checkpoint is exported."""
    output: pathlib.Path = pathlib.Path("lifter.onnx")
    """The ONNX file to write; the JAX form (suffix .jax_export) and the metadata (.json) go beside it."""
    onnx: bool = True
    """Write the ONNX model (needs `pip install 'jaxpose[export]'`); --no-onnx writes the JAX form only."""
    flip: bool = False
    """Test-time flip augmentation inside both exported forms (`jaxpose.flip`): each pose and its mirror
    image are lifted and averaged, at twice the cost; the metadata's test_time_flip says which."""
    min_confidence: float = DEFAULT_MIN_CONFIDENCE
    """Joints scored below this are lifted as missing, inside the exported graph.  Default: the threshold the
    run was trained with (its run.json; with RUN_DIR given, the default below is it), else 0.05, as
    `jaxpose.predict`; a value given always wins."""
    overwrite: bool = False
    """Replace existing output files; without it the command stops before any work.  A file of the run
    directory is never replaced."""


def check_outputs(args: ExportArgs) -> None:
    """Check the files the export writes (metadata, JAX form, ONNX unless --no-onnx) before any work with
    `check_output`: the run directory is its input, so nothing is written inside it."""
    if args.output.is_dir():
        check_output(args.output, args.overwrite)  # refused as a folder
    output = args.output.with_suffix(".onnx")
    paths = [output.with_suffix(".json"), output.with_suffix(JAX_SUFFIX)] + ([output] if args.onnx else [])
    for path in paths:
        check_output(path, args.overwrite, [args.run_dir])


def main(argv: list[str] | None = None) -> None:
    args, run, _ = parse_with_run(ExportArgs, argv, __doc__, "python -m jaxpose.export", run_field="run_dir")
    try:
        check_outputs(args)
        lifter = load(run)
        if not 0.0 <= args.min_confidence <= 1.0:
            raise ValueError(f"--min-confidence must lie in [0, 1], got {args.min_confidence}")
    except (FileNotFoundError, checkpoint.CheckpointError, OutputError, ValueError) as error:
        raise SystemExit(f"error: {error}") from None
    output = args.output.with_suffix(".onnx")
    with atomic_output(output.with_suffix(".json")) as temporary:
        temporary.write_text(json.dumps(metadata(lifter, args.flip, args.min_confidence), indent=2) + "\n")
    print(f"wrote {export_jax(lifter, output.with_suffix(JAX_SUFFIX), args.flip, args.min_confidence)} and {output.with_suffix('.json')}")
    if not args.onnx:
        return
    try:
        print(f"wrote {export_onnx(lifter, output, args.flip, args.min_confidence)}")
    except ImportError as error:
        raise SystemExit(f"error: the ONNX export needs jax2onnx and onnx ({error}); pip install 'jaxpose[export]'") from None
    except Exception as error:  # noqa: BLE001 - a conversion failure: report it, the JAX form is written
        raise SystemExit(
            f"error: jax2onnx could not convert the lifter ({type(error).__name__}: {error}); only the JAX form"
            f" {output.with_suffix(JAX_SUFFIX)} was written"
        ) from None


if __name__ == "__main__":
    main()
