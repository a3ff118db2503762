"""detection stage of dynslam_lab."""
