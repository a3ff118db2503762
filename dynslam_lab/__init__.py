"""dynslam_lab: visual RGB-D SLAM in dynamic scenes, written to be read.

The package is organised by stage, in the order a frame travels through it:
``datasets`` -> ``features`` -> ``detection`` -> ``dynamic`` -> ``slam`` -> ``mapping``,
with ``evaluation`` (ATE/RPE) and ``viz`` (matplotlib, viser) beside them.
"""

__version__ = "0.1.0"
