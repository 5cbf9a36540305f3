"""Single-frame 3-D occupancy from a dense virtual array (the paper's Table 4).

One stage per module:

==================  ==========================================================
``point_cloud``     :func:`extract_point_cloud`: voxels of an RAE cube at or
                    above its 99.9th power percentile, radar frame -> scene
                    frame, normalised (log) intensity
``gating``          :func:`reference_points`: area-weighted samples of the
                    clean mesh kept by line of sight, the 0 dB beam limits,
                    the polar voxel grid and the intensity gate (>= 0.1);
                    :func:`check_overlap` (mesh in the radar's view?)
``metrics``         :func:`occupancy_metrics`: precision, recall, F1,
                    accuracy, RMSE, Chamfer and relative Chamfer distance
                    (cKDTree, tau = 0.5 m)
``ply``             :func:`write_ply` / :func:`read_ply` (``intensity``
                    property; binary little endian or ASCII)
``plot``            :func:`save_occupancy_figure` (3-D scatter PNG)
``pipeline``        :func:`occupancy`: render a dense array (single bounce),
                    RAE cube, point cloud, reference, metrics;
                    :func:`extruded_baseline` for a near-1-D array,
                    :func:`save_result` (PLY + JSON + PNG folder)
==================  ==========================================================

The RAE cube itself is :func:`sionna_mmir.processing.rae.rae_cube`.  Frames:
points are metres in the scene frame; the radar frame is ``+x`` boresight,
``+y`` left, ``+z`` up, mapped by the radar pose ``p_scene = position + R p``.
"""
from __future__ import annotations

from .gating import (ReferenceSet, beam_mask, check_overlap, line_of_sight, read_meshes,
                     reference_points, sample_surface, voxel_of)
from .metrics import METRIC_KEYS, nearest_distances, occupancy_metrics
from .pipeline import (DENSE_RENDER, OccupancyResult, dense_cube, extruded_baseline, occupancy,
                       posed, render_adc, save_result, score)
from .plot import save_occupancy_figure
from .ply import read_ply, write_ply
from .point_cloud import (PointCloud, extract_point_cloud, normalised_intensity, radar_to_scene,
                          scene_to_radar)

__all__ = [
    "DENSE_RENDER", "METRIC_KEYS", "OccupancyResult", "PointCloud", "ReferenceSet", "beam_mask",
    "check_overlap", "dense_cube", "extract_point_cloud", "extruded_baseline", "line_of_sight",
    "nearest_distances", "normalised_intensity", "occupancy", "occupancy_metrics", "posed",
    "radar_to_scene", "read_meshes", "read_ply", "reference_points", "render_adc",
    "sample_surface", "save_occupancy_figure", "save_result", "scene_to_radar", "score", "voxel_of",
    "write_ply",
]
