"""Matplotlib figures of skeletons for experiment reports and notebooks.

Figures are built with `matplotlib.figure.Figure`, not pyplot: no global state, no display needed,
nothing is ever shown; the caller saves them (`save_figure`) or lets a notebook render them.
`save_pose_animation` writes a pose sequence as a .gif or .mp4 instead.

Conventions (docs/conventions.md): 2D keypoints in pixels, image y pointing down; 3D poses in mm in
a camera frame (x right, y down, z forward).  3D panels plot (x, z, -y), so the person stands
upright and depth goes into the screen, with equal scale on all axes.  Bones are coloured by the
side of their child joint, read from the skeleton's (left, right) pairs: left LEFT_COLOR, right
RIGHT_COLOR, the rest (spine, head, root) CENTER_COLOR.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib import animation
from matplotlib import pyplot as plt
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from tqdm.auto import tqdm

from jaxpose.skeleton import Skeleton

LEFT_COLOR = "tab:blue"
RIGHT_COLOR = "tab:red"
CENTER_COLOR = "0.25"
# Ground truth under a prediction: one neutral dashed colour, so the prediction keeps the side colours.
GT_STYLE = {"color": "0.55", "linestyle": "--", "linewidth": 1.5, "marker": ""}
# Thin and dotted with small crosses at the joints, so the detections stay visible underneath.
REPROJECTION_STYLE = {"color": "black", "linestyle": ":", "linewidth": 1.0, "marker": "x", "markersize": 3.0}
# A three-quarter view from slightly above and behind the camera.
VIEW_3D = {"elev": 12.0, "azim": -70.0}
ANIMATION_SUFFIXES = (".gif", ".mp4")
# 4 x 4 inch panels at 100 dpi: 400 px a panel keeps the labels readable and a .gif frame under 1 MB.
ANIMATION_DPI = 100


def _as_array(values, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """`values` as a float array of `shape` (None = any size), or a ValueError naming it."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != len(shape) or any(e is not None and e != g for e, g in zip(shape, array.shape)):
        expected = tuple("*" if e is None else e for e in shape)
        raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    return array


def _joint_colors(skeleton: Skeleton) -> np.ndarray:
    colors = np.full(skeleton.num_joints, CENTER_COLOR, dtype=object)
    for left, right in skeleton.left_right_pairs:
        colors[left], colors[right] = LEFT_COLOR, RIGHT_COLOR
    return colors


def _draw_bones(ax: Axes, points: np.ndarray, skeleton: Skeleton, drawn: np.ndarray, style: dict) -> list[Line2D]:
    """One line per bone whose two joints are `drawn`, in `skeleton.bones` order.

    Coloured by side unless `style` sets a colour.
    """
    colors = _joint_colors(skeleton)
    lines = []
    for child, parent in skeleton.bones:
        if drawn[child] and drawn[parent]:
            # Axes.plot takes (x, y) and Axes3D.plot (x, y, z): one column per coordinate.
            lines += ax.plot(*points[[parent, child]].T, **{"color": colors[child], "linewidth": 2.0, **style})
    return lines


def _to_display(points: np.ndarray) -> np.ndarray:
    """Camera-frame (x, y, z) -> plotted (x, z, -y): y points down in the camera, up on screen."""
    return np.stack([points[..., 0], points[..., 2], -points[..., 1]], axis=-1)


def _fit_cube(ax, points: np.ndarray, keep_existing: bool) -> None:
    """Equal-scale cubic limits around the finite `points` (plotted coordinates).

    With `keep_existing`, the cube also covers the current limits (an overlay on a drawn pose).
    """
    finite = points[np.isfinite(points).all(axis=-1)]
    if finite.size == 0:
        return
    center = (finite.min(axis=0) + finite.max(axis=0)) / 2
    # 10% margin, and at least 1 mm, so a single point still gets a box.
    half = max(np.ptp(finite, axis=0).max() / 2 * 1.1, 1.0)
    low, high = center - half, center + half
    if keep_existing:
        current = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
        low, high = np.minimum(low, current[:, 0]), np.maximum(high, current[:, 1])
        center, half = (low + high) / 2, (high - low).max() / 2
    ax.set_xlim3d(center[0] - half, center[0] + half)
    ax.set_ylim3d(center[1] - half, center[1] + half)
    ax.set_zlim3d(center[2] - half, center[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))


def plot_pose_2d(
    ax: Axes, keypoints, skeleton: Skeleton, confidence=None, joint_size: float = 12.0, **style
) -> list[Line2D]:
    """Draw 2D keypoints [J, 2] (pixels) on image axes: bones as lines, joints as dots of area `joint_size` (0: none).

    Joints with confidence <= 0 or non-finite coordinates are not drawn, nor are their bones.
    `style`: Line2D properties for the bones (a `color` also colours the dots).  Makes the axes
    equal-aspect with y pointing down, as in the image.  Returns the bone lines.
    """
    keypoints = _as_array(keypoints, (skeleton.num_joints, 2), "keypoints")
    visible = np.isfinite(keypoints).all(axis=-1)
    if confidence is not None:
        visible &= _as_array(confidence, (skeleton.num_joints,), "confidence") > 0
    lines = _draw_bones(ax, keypoints, skeleton, visible, style)
    if joint_size > 0:
        dot_colors = style.get("color", list(_joint_colors(skeleton)[visible]))
        ax.scatter(
            keypoints[visible, 0], keypoints[visible, 1], s=joint_size, c=dot_colors, alpha=style.get("alpha"), zorder=3
        )
    ax.set_aspect("equal")
    if not ax.yaxis_inverted():  # invert_yaxis toggles, so guard repeated calls
        ax.invert_yaxis()
    return lines


def plot_pose_3d(ax, pose, skeleton: Skeleton, **style) -> list[Line2D]:
    """Draw a 3D pose [J, 3] (mm, camera frame) on 3D axes, upright, at equal scale.

    Every bone gets a line, in `skeleton.bones` order (a bone with a non-finite joint is an empty
    line), so callers can animate them.  `style`: Line2D properties.  Calling it again on the same
    axes (e.g. ground truth then prediction) grows the limits to fit both.  Returns the bone lines.
    """
    pose = _as_array(pose, (skeleton.num_joints, 3), "pose")
    points = _to_display(pose)
    had_data = ax.has_data()
    every_joint = np.ones(skeleton.num_joints, bool)
    lines = _draw_bones(ax, points, skeleton, every_joint, {"marker": "o", "markersize": 2.5, **style})
    _fit_cube(ax, points, keep_existing=had_data)
    ax.set_xlabel("x (mm)", fontsize=7)
    ax.set_ylabel("z (mm)", fontsize=7)
    ax.set_zlabel("-y (mm)", fontsize=7)
    ax.tick_params(labelsize=6)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))  # the default crowds the tick labels of small panels
    return lines


def _add_3d_axes(fig: Figure, *subplot_spec):
    ax = fig.add_subplot(*subplot_spec, projection="3d")
    ax.view_init(**VIEW_3D)
    return ax


def _set_image_size(ax: Axes, image_size: tuple[int, int] | None) -> None:
    """Frame the whole image, (width, height) in pixels, y down; None keeps the autoscaled limits."""
    if image_size is not None:
        width, height = image_size
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)


def _side_legend(ax: Axes, extra: tuple[tuple[str, dict], ...] = ()) -> None:
    """Legend of the side colours plus `extra` (label, line style) entries."""
    entries = (("left", {"color": LEFT_COLOR}), ("right", {"color": RIGHT_COLOR}), ("centre", {"color": CENTER_COLOR}))
    handles = [Line2D([], [], **{"linewidth": 2.0, **style}, label=label) for label, style in entries + extra]
    ax.legend(handles=handles, fontsize=7, loc="upper left", framealpha=0.8)


def figure_lifting(
    keypoints2d, pose3d, skeleton: Skeleton, image_size: tuple[int, int] | None = None, title: str | None = None,
    confidence=None,
) -> Figure:
    """The 2D detection [J, 2] beside the lifted 3D pose [J, 3]; `image_size` = (width, height) pixels."""
    fig = Figure(figsize=(9.0, 4.5), layout="constrained")
    ax2d = fig.add_subplot(1, 2, 1)
    plot_pose_2d(ax2d, keypoints2d, skeleton, confidence)
    _set_image_size(ax2d, image_size)
    ax2d.set_title("2D detection (px)", fontsize=9)
    _side_legend(ax2d)
    ax3d = _add_3d_axes(fig, 1, 2, 2)
    plot_pose_3d(ax3d, pose3d, skeleton)
    ax3d.set_title("lifted 3D pose (mm)", fontsize=9)
    if title:
        fig.suptitle(title)
    return fig


def figure_gt_vs_prediction(gt, pred, skeleton: Skeleton, titles=None, max_samples: int = 4) -> Figure:
    """A row of 3D panels, one per sample (the first `max_samples`), ground truth dashed grey under the prediction.

    gt, pred: [N, J, 3] mm; any alignment (root, Procrustes) is the caller's.  `titles`: one per sample.
    """
    gt = _as_array(gt, (None, skeleton.num_joints, 3), "gt")
    pred = _as_array(pred, gt.shape, "pred")
    count = min(len(gt), max_samples)
    if count < 1:
        raise ValueError(f"figure_gt_vs_prediction: nothing to draw ({len(gt)} samples, max_samples={max_samples})")
    fig = Figure(figsize=(3.8 * count, 3.8), layout="constrained")
    for i in range(count):
        ax = _add_3d_axes(fig, 1, count, i + 1)
        plot_pose_3d(ax, gt[i], skeleton, **GT_STYLE)
        plot_pose_3d(ax, pred[i], skeleton)
        ax.set_title(titles[i] if titles is not None else f"sample {i}", fontsize=9)
    _side_legend(fig.axes[0], (("ground truth", GT_STYLE),))
    return fig


def figure_multiview_sample(
    keypoints2d, confidence, projections_of_triangulation, predictions, skeleton: Skeleton,
    image_size: tuple[int, int] | None = None,
) -> Figure:
    """One column per view: the detections [C, J, 2] (confidence [C, J]; 0 = not drawn) with the
    triangulation re-projected [C, J, 2] dotted black, and below, when given, that view's predicted
    pose [C, J, 3] in its camera frame.  Either optional input may be None.
    """
    keypoints2d = _as_array(keypoints2d, (None, skeleton.num_joints, 2), "keypoints2d")
    views = len(keypoints2d)
    confidence = _as_array(confidence, keypoints2d.shape[:2], "confidence")
    rows = 1 if predictions is None else 2
    fig = Figure(figsize=(3.4 * views, 3.4 * rows), layout="constrained")
    if projections_of_triangulation is not None:
        projections_of_triangulation = _as_array(
            projections_of_triangulation, keypoints2d.shape, "projections_of_triangulation"
        )
    if predictions is not None:
        predictions = _as_array(predictions, (views, skeleton.num_joints, 3), "predictions")
    for view in range(views):
        ax = fig.add_subplot(rows, views, view + 1)
        plot_pose_2d(ax, keypoints2d[view], skeleton, confidence[view])
        if projections_of_triangulation is not None:
            plot_pose_2d(ax, projections_of_triangulation[view], skeleton, joint_size=0.0, **REPROJECTION_STYLE)
        _set_image_size(ax, image_size)
        ax.set_title(f"view {view}: detections (px)", fontsize=9)
        if predictions is not None:
            ax3d = _add_3d_axes(fig, rows, views, views + view + 1)
            plot_pose_3d(ax3d, predictions[view], skeleton)
            ax3d.set_title(f"view {view}: prediction (mm)", fontsize=9)
    extra = (("triangulation re-projected", REPROJECTION_STYLE),) if projections_of_triangulation is not None else ()
    _side_legend(fig.axes[0], extra)
    return fig


def figure_loss_curves(
    history: dict[str, list[tuple[int, float]]], log_y: bool = True, overlay: bool = False
) -> Figure:
    """Loss terms against the step: one panel per term, or all on one panel if `overlay`.

    history: term name -> [(step, value), ...].  The y axis is logarithmic when `log_y` and every
    finite value on the panel is positive; otherwise linear (e.g. a loss that can go negative).
    """
    if not history:
        raise ValueError("figure_loss_curves: history is empty")
    terms = list(history.items())
    panels = [terms] if overlay else [[term] for term in terms]
    columns = min(len(panels), 3)
    rows = math.ceil(len(panels) / columns)
    fig = Figure(figsize=(4.0 * columns, 3.0 * rows), layout="constrained")
    for i, panel in enumerate(panels):
        ax = fig.add_subplot(rows, columns, i + 1)
        values_on_panel = []
        for name, points in panel:
            steps_values = np.asarray(points, np.float64).reshape(-1, 2)  # reshape: an empty list too
            ax.plot(steps_values[:, 0], steps_values[:, 1], label=name, linewidth=1.2)
            values_on_panel.append(steps_values[:, 1])
        values = np.concatenate(values_on_panel)
        finite = values[np.isfinite(values)]
        if log_y and finite.size and (finite > 0).all():
            ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.grid(True, alpha=0.3)
        if overlay:
            ax.legend(fontsize=8)
        else:
            name, points = panel[0]
            ax.set_title(name if points else f"{name} (no data)", fontsize=9)
    return fig


def _movie_writer(path: Path, fps: float) -> tuple[animation.AbstractMovieWriter, dict[str, str]]:
    """The matplotlib writer for `path`'s suffix and the rcParams it runs under; ValueError naming what is wrong."""
    if not fps > 0:
        raise ValueError(f"{path}: fps must be positive, got {fps}")
    suffix = path.suffix.lower()
    if suffix == ".gif":
        return animation.PillowWriter(fps=fps), {}
    if suffix != ".mp4":
        raise ValueError(f"{path}: the suffix must be one of {ANIMATION_SUFFIXES}")
    ffmpeg = _ffmpeg_executable()
    if ffmpeg is None:
        raise ValueError(
            f"{path}: an .mp4 needs the ffmpeg encoder: pip install 'jaxpose[video]' (it bundles one) or put"
            " ffmpeg on PATH; a .gif needs nothing more"
        )
    return animation.FFMpegWriter(fps=fps), {"animation.ffmpeg_path": ffmpeg}


@contextlib.contextmanager
def _starting_ffmpeg():
    """Silence JAX's warning on a fork of its threads: subprocess forks and at once execs ffmpeg, taking no lock."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        yield


def _ffmpeg_executable() -> str | None:
    """The ffmpeg matplotlib is set to use (by default the one on PATH), else the one imageio-ffmpeg bundles."""
    if animation.FFMpegWriter.isAvailable():
        return animation.FFMpegWriter.bin_path()
    try:
        import imageio_ffmpeg  # the 'video' extra; imported here as only an .mp4 needs it

        with _starting_ffmpeg():  # it runs `ffmpeg -version` to check the binary
            return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):  # RuntimeError: installed without a binary for this platform
        return None


def check_animation_path(path, fps: float = 10.0) -> None:
    """Raise the ValueError `save_pose_animation` would for `path` and `fps` (suffix, frame rate, encoder), before
    any work is done."""
    _movie_writer(Path(path), fps)


def _fix_image_frame(ax: Axes, keypoints: np.ndarray, image_size: tuple[float, float] | None) -> None:
    """Fixed 2D limits: the whole image when its size is known, else every finite keypoint [..., 2] plus a margin."""
    if image_size is not None:
        _set_image_size(ax, image_size)
        return
    finite = keypoints[np.isfinite(keypoints).all(axis=-1)]
    if finite.size:
        low, high = finite.min(axis=0), finite.max(axis=0)
        margin = max(0.1 * np.ptp(finite, axis=0).max(), 1.0)
        ax.set_xlim(low[0] - margin, high[0] + margin)
        ax.set_ylim(high[1] + margin, low[1] - margin)  # y down, as in the image


def save_pose_animation(
    path, poses, skeleton: Skeleton, keypoints2d=None, confidence=None,
    image_size: tuple[float, float] | None = None, titles=None, fps: float = 10.0,
) -> Path:
    """Animate a 3D pose sequence [T, J, 3] (mm, camera frame), beside its 2D input [T, J, 2] (pixels;
    confidence [T, J], 0 = not drawn) when given, to `path`: a .gif (Pillow) or an .mp4 (ffmpeg, see
    `check_animation_path`).  Returns the path.

    Limits are fixed over the whole sequence, so motion is not hidden by rescaling: the 2D panel
    frames the image of `image_size` (width, height) or else every drawn keypoint, the 3D cube every
    finite pose.  A frame whose pose is not finite (not lifted) has an empty 3D panel marked so.
    `titles`: one per frame.  One figure is redrawn and grabbed frame by frame; an .mp4 is streamed
    to ffmpeg, while a .gif holds its frames (about 1 MB each) until written.
    """
    poses = _as_array(poses, (None, skeleton.num_joints, 3), "poses")
    count = len(poses)
    if count == 0:
        raise ValueError("save_pose_animation: no frames")
    path = Path(path)
    writer, rc = _movie_writer(path, fps)
    panels = 1 if keypoints2d is None else 2
    fig = Figure(figsize=(4.0 * panels, 4.0), dpi=ANIMATION_DPI, layout="constrained")
    if keypoints2d is not None:
        keypoints2d = _as_array(keypoints2d, (count, skeleton.num_joints, 2), "keypoints2d")
        if confidence is not None:  # undetected joints are not drawn, nor framed
            confidence = _as_array(confidence, keypoints2d.shape[:2], "confidence")
            keypoints2d = np.where(confidence[..., None] > 0, keypoints2d, np.nan)
        ax2d = fig.add_subplot(1, 2, 1)
        _fix_image_frame(ax2d, keypoints2d, image_size)
        ax2d.set_title("2D input", fontsize=9)
        ax2d.set_xlabel("x (px)", fontsize=7)
        ax2d.set_ylabel("y (px)", fontsize=7)
        ax2d.tick_params(labelsize=6)
    ax3d = _add_3d_axes(fig, 1, panels, panels)
    points = _to_display(poses)
    lines = plot_pose_3d(ax3d, poses[0], skeleton)
    _fit_cube(ax3d, points.reshape(-1, 3), keep_existing=False)
    ax3d.set_title("lifted 3D pose (mm)", fontsize=9)
    not_lifted = ax3d.text2D(0.5, 0.5, "not lifted", transform=ax3d.transAxes, ha="center", color="0.4")
    _side_legend(ax3d)  # the cube's corners stay clear of a moving pose; the 2D panel's may not
    path.parent.mkdir(parents=True, exist_ok=True)
    with mpl.rc_context(rc), _starting_ffmpeg():
        with writer.saving(fig, path, dpi=ANIMATION_DPI):
            for t in tqdm(range(count), desc=f"writing {path.name}", unit="frame"):
                if keypoints2d is not None:
                    for artist in [*ax2d.lines, *ax2d.collections]:  # the previous frame; limits and legend stay
                        artist.remove()
                    plot_pose_2d(ax2d, keypoints2d[t], skeleton)
                for line, (child, parent) in zip(lines, skeleton.bones):
                    line.set_data_3d(*points[t, [parent, child]].T)
                not_lifted.set_visible(not np.isfinite(poses[t]).all())
                if titles is not None:
                    fig.suptitle(titles[t], fontsize=10)
                if t == 0:  # lay out once: laid out per frame, the panels would shift as the pose moves
                    fig.draw_without_rendering()
                    fig.set_layout_engine("none")
                writer.grab_frame()
    return path


def figure_rig(
    centres, rotations, camera_names, reference: tuple[np.ndarray, np.ndarray] | None = None
) -> Figure:
    """A camera rig from above and from the side: centres [C, 3] (mm) and world-to-camera rotations
    [C, 3, 3], optionally beside a reference rig (centres, rotations) in the same world frame.

    The views are along the principal axes of the camera centres (of the reference, when given):
    cameras around a scene lie near a plane, so the first view looks down on it whatever the
    world's up axis.  Each camera is a dot with its optical axis as a line.
    """
    centres = _as_array(centres, (None, 3), "centres")
    rotations = _as_array(rotations, (len(centres), 3, 3), "rotations")
    frame_centres = centres if reference is None else np.asarray(reference[0], np.float64)
    middle = frame_centres.mean(0)
    axes = np.linalg.svd(frame_centres - middle)[2]  # rows: in-plane, in-plane, normal
    extent = np.abs(frame_centres - middle).max()
    fig = Figure(figsize=(10, 4.8), layout="constrained")
    rigs = [("recovered", centres, rotations, {"color": "tab:red", "marker": "x"})]
    if reference is not None:
        rigs.insert(0, ("reference", reference[0], reference[1], {"color": "0.45", "marker": "o", "fillstyle": "none"}))
    for panel, (title, pair) in enumerate((("from above", (0, 1)), ("from the side", (0, 2)))):
        ax = fig.add_subplot(1, 2, panel + 1)
        for label, rig_centres, rig_rotations, style in rigs:
            planar = (np.asarray(rig_centres) - middle) @ axes[list(pair)].T
            # A camera's optical axis in the world is the third row of its rotation.
            axis = np.asarray(rig_rotations)[:, 2] @ axes[list(pair)].T * 0.25 * extent
            ax.plot(*planar.T, linestyle="", markersize=8, label=label, **style)
            for c, name in enumerate(camera_names):
                ax.plot(*np.stack([planar[c], planar[c] + axis[c]]).T, color=style["color"], linewidth=1.2)
                if label == rigs[-1][0]:
                    ax.annotate(str(name), planar[c], textcoords="offset points", xytext=(6, 6), fontsize=7)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("principal axis 1 of the camera centres (mm)", fontsize=7)
        ax.set_ylabel(f"{'principal axis 2' if pair[1] == 1 else 'normal of the camera plane'} (mm)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
    fig.axes[0].legend(fontsize=7, loc="best")
    return fig


def save_figure(fig: Figure, path, dpi: int = 150) -> Path:
    """Save `fig` as PNG (creating the folder) and close it, so report loops do not accumulate figures."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, format="png", bbox_inches="tight")
    plt.close(fig)  # releases pyplot-made figures; a no-op for the plain Figures built here
    return path
