"""The files users bring and take away, read and written, knowing no data set.

Calibrations (`rig_calibration`: Anipose / Pose2Sim / FreeMoCap TOML, EasyMocap YAML, the jaxpose
camera file of `camera_file`, Human3.6M's cameras.h5), keypoints (`keypoint_files`: OpenPose JSON
frames, COCO results), poses out (`trc`), and the small readers and the one error they share
(`files`, `errors`).  Nothing here imports a data set, the rig project or training.
"""
