"""dynamic stage of dynslam_lab."""
