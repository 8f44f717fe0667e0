"""Tests of jaxpose.viz: expected panels and lines, files written, missing joints skipped."""

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from matplotlib import pyplot as plt
from matplotlib.figure import Figure
from PIL import Image

from jaxpose import viz
from jaxpose.skeleton import H36M_17, HUMANEVA_15

# A person standing and facing the camera, camera frame in mm (x right, y down, z forward), pelvis at
# the origin: their left side is at +x.  Keyed by the joint names of both skeletons.
STANDING = {
    "Hip": (0, 0, 0), "Pelvis": (0, 0, 0), "Spine": (0, -230, 10), "Thorax": (0, -480, 0),
    "Neck/Nose": (0, -580, -60), "Head": (0, -700, 0),
    "LHip": (130, 0, 0), "LKnee": (140, 450, 20), "LFoot": (150, 880, 40), "LAnkle": (150, 880, 40),
    "RHip": (-130, 0, 0), "RKnee": (-140, 450, 20), "RFoot": (-150, 880, 40), "RAnkle": (-150, 880, 40),
    "LShoulder": (160, -450, 0), "LElbow": (250, -200, 20), "LWrist": (330, 20, -60),
    "RShoulder": (-160, -450, 0), "RElbow": (-250, -200, 20), "RWrist": (-330, 20, -60),
}
SKELETONS = [H36M_17, HUMANEVA_15]


def standing_pose(skeleton):
    return np.array([STANDING[name] for name in skeleton.joint_names], np.float64)


def project(pose, depth=4000.0, focal=1000.0, center=(500.0, 500.0)):
    """Pinhole projection of a pose placed `depth` mm in front of the camera."""
    z = pose[:, 2] + depth
    return np.stack([focal * pose[:, 0] / z + center[0], focal * pose[:, 1] / z + center[1]], axis=-1)


def num_bones(skeleton):
    return len(skeleton.bones)


@pytest.mark.parametrize("skeleton", SKELETONS, ids=lambda s: s.name)
def test_plot_pose_2d_colours_sides_and_inverts_y(skeleton):
    fig = Figure()
    ax = fig.add_subplot()
    lines = viz.plot_pose_2d(ax, project(standing_pose(skeleton)), skeleton)
    assert len(lines) == num_bones(skeleton) == len(ax.lines)
    colors = [line.get_color() for line in lines]
    for (child, _), color in zip(skeleton.bones, colors):
        name = skeleton.joint_names[child]
        expected = {"L": viz.LEFT_COLOR, "R": viz.RIGHT_COLOR}.get(name[0], viz.CENTER_COLOR)
        assert color == expected, name
    assert ax.yaxis_inverted()
    viz.plot_pose_2d(ax, project(standing_pose(skeleton)), skeleton)
    assert ax.yaxis_inverted(), "a second call must not flip the axis back"


def test_plot_pose_2d_skips_missing_joints():
    keypoints = project(standing_pose(H36M_17))
    confidence = np.ones(17)
    confidence[H36M_17.index("LWrist")] = 0.0  # a leaf: one bone
    confidence[H36M_17.index("RKnee")] = 0.0  # two bones
    keypoints[H36M_17.index("RKnee")] = np.nan  # missing joints may carry garbage
    fig = Figure()
    ax = fig.add_subplot()
    lines = viz.plot_pose_2d(ax, keypoints, H36M_17, confidence)
    assert len(lines) == num_bones(H36M_17) - 3
    assert len(ax.collections[0].get_offsets()) == 15
    for line in lines:
        assert np.isfinite(line.get_xydata()).all()


@pytest.mark.parametrize("skeleton", SKELETONS, ids=lambda s: s.name)
def test_plot_pose_3d_is_upright_and_equal_scale(skeleton):
    fig = Figure()
    ax = fig.add_subplot(projection="3d")
    lines = viz.plot_pose_3d(ax, standing_pose(skeleton), skeleton)
    assert len(lines) == num_bones(skeleton)
    line_to = {skeleton.joint_names[child]: line for line, (child, _) in zip(lines, skeleton.bones)}
    head_bone = line_to["Head"]
    foot_bone = line_to.get("LFoot", line_to.get("LAnkle"))
    # Plotted vertical is -y: the head is above the feet.
    assert head_bone.get_data_3d()[2].max() > 500 and foot_bone.get_data_3d()[2].min() < -800
    spans = [np.ptp(ax.get_xlim3d()), np.ptp(ax.get_ylim3d()), np.ptp(ax.get_zlim3d())]
    np.testing.assert_allclose(spans, spans[0])
    assert spans[0] >= 1580  # feet to head fits


def test_plot_pose_3d_keeps_one_line_per_bone_with_a_missing_joint():
    pose = standing_pose(H36M_17)
    pose[H36M_17.index("LWrist")] = np.nan
    fig = Figure()
    ax = fig.add_subplot(projection="3d")
    assert len(viz.plot_pose_3d(ax, pose, H36M_17)) == num_bones(H36M_17)
    assert np.isfinite([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()]).all()


def test_plot_pose_3d_overlay_grows_limits_to_both_poses():
    fig = Figure()
    ax = fig.add_subplot(projection="3d")
    pose = standing_pose(H36M_17)
    viz.plot_pose_3d(ax, pose, H36M_17)
    viz.plot_pose_3d(ax, pose + [2000.0, 0.0, 0.0], H36M_17, color="k")
    low, high = ax.get_xlim3d()
    assert low <= -330 and high >= 2330
    assert len(ax.lines) == 2 * num_bones(H36M_17)


def test_wrong_shape_is_a_value_error():
    fig = Figure()
    with pytest.raises(ValueError, match=r"pose: expected shape \(17, 3\), got \(15, 3\)"):
        viz.plot_pose_3d(fig.add_subplot(projection="3d"), standing_pose(HUMANEVA_15), H36M_17)


@pytest.mark.parametrize("skeleton", SKELETONS, ids=lambda s: s.name)
def test_figure_lifting(skeleton, tmp_path):
    pose = standing_pose(skeleton)
    fig = viz.figure_lifting(project(pose), pose, skeleton, image_size=(1000, 1000), title="lifting")
    ax2d, ax3d = fig.axes
    assert len(ax2d.lines) == len(ax3d.lines) == num_bones(skeleton)
    assert ax2d.get_ylim() == (1000, 0)
    assert fig.get_suptitle() == "lifting"
    path = viz.save_figure(fig, tmp_path / "lifting.png")
    assert path.stat().st_size > 20_000


def test_figure_gt_vs_prediction_limits_panels():
    gt = np.stack([standing_pose(H36M_17)] * 6)
    pred = gt + np.random.default_rng(0).normal(scale=30.0, size=gt.shape)
    fig = viz.figure_gt_vs_prediction(gt, pred, H36M_17, titles=[f"s{i}" for i in range(6)], max_samples=4)
    assert len(fig.axes) == 4
    assert [ax.get_title() for ax in fig.axes] == ["s0", "s1", "s2", "s3"]
    for ax in fig.axes:
        assert len(ax.lines) == 2 * num_bones(H36M_17)
    assert fig.axes[0].get_legend() is not None
    with pytest.raises(ValueError, match="pred"):
        viz.figure_gt_vs_prediction(gt, pred[:, :16], H36M_17)


@pytest.mark.parametrize("skeleton", SKELETONS, ids=lambda s: s.name)
def test_figure_multiview_sample(skeleton):
    pose = standing_pose(skeleton)
    views = 3
    keypoints = np.stack([project(pose, depth=3000.0 + 500.0 * c) for c in range(views)])
    confidence = np.ones((views, skeleton.num_joints))
    confidence[1, skeleton.index("LWrist")] = 0.0
    fig = viz.figure_multiview_sample(keypoints, confidence, keypoints + 3.0, np.stack([pose] * views), skeleton)
    assert len(fig.axes) == 2 * views
    bones = num_bones(skeleton)
    panels_2d = [ax for ax in fig.axes if ax.name != "3d"]
    panels_3d = [ax for ax in fig.axes if ax.name == "3d"]
    # Detections (one bone fewer in view 1) plus the re-projection; one pose per 3D panel.
    assert [len(ax.lines) for ax in panels_2d] == [2 * bones, 2 * bones - 1, 2 * bones]
    assert [len(ax.lines) for ax in panels_3d] == [bones] * views
    only_2d = viz.figure_multiview_sample(keypoints, confidence, None, None, skeleton, image_size=(1000, 1000))
    assert len(only_2d.axes) == views


def test_figure_loss_curves():
    history = {
        "total": [(step, 10.0 / (step + 1)) for step in range(0, 100, 10)],
        "reprojection": [(step, 5.0 / (step + 1)) for step in range(0, 100, 10)],
        "log_likelihood": [(step, -1.0 * step) for step in range(0, 100, 10)],
        "unused": [],
    }
    fig = viz.figure_loss_curves(history)
    assert len(fig.axes) == 4
    assert [ax.get_yscale() for ax in fig.axes] == ["log", "log", "linear", "linear"]
    assert all(len(ax.lines) == 1 for ax in fig.axes)
    assert fig.axes[3].get_title() == "unused (no data)"
    overlaid = viz.figure_loss_curves({k: history[k] for k in ("total", "reprojection")}, overlay=True)
    assert len(overlaid.axes) == 1 and len(overlaid.axes[0].lines) == 2
    assert overlaid.axes[0].get_yscale() == "log"
    assert viz.figure_loss_curves(history, log_y=False).axes[0].get_yscale() == "linear"
    with pytest.raises(ValueError, match="empty"):
        viz.figure_loss_curves({})


def test_save_pose_animation_of_3d_poses_alone(tmp_path):
    frames = 5
    pose = standing_pose(HUMANEVA_15)
    poses = np.stack([pose + [0.0, 0.0, 100.0 * t] for t in range(frames)])
    poses[2] = np.nan  # a frame not lifted is drawn empty, not an error
    path = viz.save_pose_animation(tmp_path / "sub" / "walk.gif", poses, HUMANEVA_15, fps=5)
    with Image.open(path) as gif:
        assert gif.n_frames == frames and gif.size == (400, 400)  # one panel
    with pytest.raises(ValueError, match=r"walk\.avi: the suffix must be one of \('\.gif', '\.mp4'\)"):
        viz.save_pose_animation(tmp_path / "walk.avi", poses, HUMANEVA_15)
    with pytest.raises(ValueError, match="fps must be positive"):
        viz.save_pose_animation(tmp_path / "walk.gif", poses, HUMANEVA_15, fps=0)


def test_save_figure_closes_pyplot_figures(tmp_path):
    fig = plt.figure()
    viz.plot_pose_2d(fig.add_subplot(), project(standing_pose(H36M_17)), H36M_17)
    path = viz.save_figure(fig, tmp_path / "pyplot.png")
    assert not plt.fignum_exists(fig.number)
    with Image.open(path) as image:
        assert image.format == "PNG" and min(image.size) > 100
