"""A user's own rig project as a data set: its recordings found and read (`project`), cameras aligned
in time (`sync`), and the one person the views agree on kept per instant (`people`)."""
