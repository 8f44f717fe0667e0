"""A user's own rig project as a data set (`project`: the folder, its settings, the loading): its
recordings found and read (`recordings`), their calibrations (`calibrations`) or the rig recovered
from them (`recovered`), cameras aligned in time (`timeline`, with offsets estimated by `sync`), and
the one person the views agree on kept per instant (`people`); one recording at a time
(`preparation`), in chunks of one shape across recordings (`geometry`), prepared once and cached
beside the recordings (`prepared`)."""
