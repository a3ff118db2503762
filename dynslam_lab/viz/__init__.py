"""viz stage of dynslam_lab."""
