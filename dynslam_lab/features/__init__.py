"""features stage of dynslam_lab."""
