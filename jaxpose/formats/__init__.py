"""The files users bring and take away, read and written, knowing no data set.

Calibrations: `rig_calibration` reads any of them into the `RigCalibration` of `calibrated_rig`
(Anipose / Pose2Sim / FreeMoCap TOML of `anipose_toml`, EasyMocap YAML of `easymocap_yaml`, the
jaxpose camera file of `camera_file`, Human3.6M's cameras.h5 of `h36m_cameras`); one camera's
intrinsics for a single-view command (`intrinsics`); camera names matched across the tools (`camera_names`).
Keypoints: per-camera OpenPose JSON frame folders and COCO results (`keypoint_files`, parsed with
`fast_json` and `coco_results` in a process pool (`file_pool`), cached by `file_cache`), the one
rule for detector scores (`confidences`), a recording's multi-view `detections_npz`,
and a file of poses to lift one at a time (`detection_file`).
Poses out: `pose_files` (JSON, npz, CSV, TRC) over `trc` (OpenSim markers).  Motion capture in: `bvh`.
The rig project folder's file names (`rig_folder`), outputs that never destroy anything (`outputs`),
and the small readers and the one error they share (`files`, `errors`).
Nothing here imports a data set, the rig project or training (tests/test_layering.py).
"""
