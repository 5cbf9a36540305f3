"""Radar datasets: render frames over scenes x radars x poses into sharded HDF5.

``spec``
    JSON spec -> :class:`DatasetSpec`; :func:`plan_frames` (one
    manifest entry per frame)
``poses``
    explicit poses, straight-line and circular trajectories
``render``
    :func:`render_frame` (manifest entry -> ADC, bit-reproducible)
``shards``
    atomic HDF5 shards with completion marker and checksum
``runner``
    :func:`run_dataset`: lock, manifest, resume, Ray or one process

``sionna-mmir dataset`` is the command line; ``docs/dataset.md`` the guide.
"""
from .poses import circle_trajectory, line_trajectory, poses_from_spec
from .render import render_frame
from .runner import read_manifest, run_dataset
from .shards import read_shard, shard_is_complete
from .spec import DatasetSpec, load_spec, parse_spec, plan_frames

__all__ = ["DatasetSpec", "circle_trajectory", "line_trajectory", "load_spec", "parse_spec",
           "plan_frames", "poses_from_spec", "read_manifest", "read_shard", "render_frame",
           "run_dataset", "shard_is_complete"]
