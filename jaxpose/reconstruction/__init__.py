"""3D motion from a calibrated rig: detections and lifted poses fused per instant (`fusion`), and the
instants no camera sees bridged or split off (`gaps`)."""
