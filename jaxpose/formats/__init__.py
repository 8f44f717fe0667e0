"""The files users bring and take away, read and written, knowing no data set.

Calibrations (`rig_calibration` reads any of them into the `RigCalibration` of `calibrated_rig`:
Anipose / Pose2Sim / FreeMoCap TOML of `anipose_toml`, EasyMocap YAML of `easymocap_yaml`, the
jaxpose camera file of `camera_file`, Human3.6M's cameras.h5 of `h36m_cameras`), keypoints
(`keypoint_files`: OpenPose JSON frames, COCO results), poses out (`trc`), and the small readers
and the one error they share (`files`, `errors`).  Nothing here imports a data set, the rig project
or training.
"""
