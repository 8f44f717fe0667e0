"""A user's own rig project as a data set (`project`: the folder, its settings, the loading): its
recordings and calibration files found, their detections read (`recordings`), their calibrations read and
matched to the cameras (`cameras`) or the rigs recovered from them, one per session (`recovered`), cameras
aligned in time, offsets given or estimated (`timeline`), and the one person the views agree on kept per
instant (`people`); one recording at a time (`preparation`), in chunks of one shape across recordings
(`geometry`), prepared once into the project's cache (`cache`) and split into training and validation
parts (`split`)."""
