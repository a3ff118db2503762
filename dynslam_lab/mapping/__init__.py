"""mapping stage of dynslam_lab."""
