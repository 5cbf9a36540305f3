"""``sionna-mmir dataset``: render a dataset spec into sharded HDF5 (parse and call)."""
from __future__ import annotations

from .args import FORMATTER


def add_parser(sub) -> None:
    p = sub.add_parser("dataset", help="render frames over scenes x radars x poses (a JSON "
                                       "spec) into sharded HDF5 with a manifest; resumable; "
                                       "Ray when installed",
                       formatter_class=FORMATTER)
    p.add_argument("spec", help="dataset spec (JSON; see docs/dataset.md)")
    p.add_argument("--out", required=True, help="output folder (manifest.json, shard_*.h5)")
    p.add_argument("--workers", type=int, default=0,
                   help="parallel Ray tasks (0: all local CPUs; 1: this process, no Ray)")
    p.add_argument("--address", default=None,
                   help="Ray cluster address (e.g. 'auto' after 'ray start --head')")
    p.add_argument("--threads", type=int, default=1, help="Dr.Jit threads per Ray task")
    p.add_argument("--frames-per-shard", type=int, default=None,
                   help="frames per HDF5 shard (default: the spec's, else 50)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a dataset of another spec in --out (re-renders all)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..dataset import load_spec, run_dataset
    from ..errors import ConfigError

    if args.threads < 1:
        raise ConfigError(f"--threads must be >= 1, got {args.threads}")
    spec = load_spec(args.spec, frames_per_shard=args.frames_per_shard)
    stats = run_dataset(spec, args.out, workers=args.workers, address=args.address,
                        overwrite=args.overwrite, progress=not args.quiet,
                        threads=args.threads)
    fps = stats["frames_per_second"]
    print(f"wrote {args.out}: {stats['frames']} frames in {stats['shards']} shard(s) "
          f"({len(stats['rendered'])} rendered, {len(stats['skipped'])} already complete), "
          f"{stats['mode']}" + (f", {fps:.2f} frames/s" if fps else ""))
    return 0
