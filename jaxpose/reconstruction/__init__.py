"""3D motion from a calibrated rig: detections and lifted poses fused per instant (`fusion`), the
instants no camera sees bridged or split off (`gaps`), a project's recordings reconstructed with a
trained lifter (`recording`), and written as .trc / .csv / .npz (`motion_files`); the command is
`jaxpose.reconstruct`."""
