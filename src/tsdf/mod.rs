//! TSDF fusion (being written).
