"""slam stage of dynslam_lab."""
