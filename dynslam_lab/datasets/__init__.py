"""Datasets: the TUM RGB-D layout (TUM, Bonn, synthetic) and the synthetic renderer."""
from .frame import Frame
from .tum import DatasetError, TumSequence, associate, load_depth, load_rgb, read_file_list

__all__ = ["Frame", "TumSequence", "DatasetError", "associate", "load_depth", "load_rgb", "read_file_list"]
