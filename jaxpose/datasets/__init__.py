"""The academic data sets as `jaxpose.data.MultiViewDataset`s: Human3.6M (`h36m`), HumanEva-I
(`humaneva`), MPI-INF-3DHP's test set (`mpi_inf_3dhp`), VideoPose3D's npz files (`videopose3d`), on the
shared base of `recordings` (one recording's views and ground truth, stacked into a data set)."""
