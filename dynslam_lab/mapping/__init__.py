"""Maps of a run: dense static point cloud (keyframes minus dynamic pixels), voxel and
statistical filters, occupancy octree (OctoMap), PLY files. See ``docs/maps.md``."""
from .dense import DenseMap, DenseMapConfig, MapQuality, build_dense_map, map_quality, read_keyframes, write_dense_map
from .octree import OctreeConfig, OctreeMap
from .ply import PlyError, read_ply, write_ply
from .pointcloud import VoxelAccumulator, backproject_frame, depth_edge_mask, statistical_outlier_mask, voxel_downsample

__all__ = [
    "DenseMap",
    "DenseMapConfig",
    "MapQuality",
    "build_dense_map",
    "map_quality",
    "read_keyframes",
    "write_dense_map",
    "OctreeConfig",
    "OctreeMap",
    "PlyError",
    "read_ply",
    "write_ply",
    "VoxelAccumulator",
    "backproject_frame",
    "depth_edge_mask",
    "statistical_outlier_mask",
    "voxel_downsample",
]
