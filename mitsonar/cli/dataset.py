"""``mitsonar dataset CONFIG -o DIR [--workers N] [--address RAY_ADDRESS]``: render a labelled dataset.

Registered by ``mitsonar.cli`` (this module does not import it). Every mistake in the config or
the folder is one line before any worker starts; running the same command again resumes.
"""
from __future__ import annotations


def cmd_dataset(args):
    from mitsonar.jobs.dataset.runner import generate_dataset

    result = generate_dataset(args.config, args.output, workers=args.workers, address=args.address,
                              threads=args.threads, progress=not args.quiet,
                              engine=args.engine)
    rate = result["rendered"] / result["seconds"] if result["seconds"] > 0 else 0.0
    print(f"{args.output}: {result['samples']} samples ({result['rendered']} rendered now, "
          f"{rate:.3g} samples/s); read with mitsonar.open_dataset({args.output!r})")
    return 0


def add_subcommands(sub):
    d = sub.add_parser("dataset", help="render a labelled dataset from a config (resumable; local processes or Ray)",
                       description="Render the randomised, labelled samples of a YAML/TOML config into "
                                   "WebDataset shards with a manifest. The same command resumes an interrupted "
                                   "run; any number of workers writes the same samples.")
    d.add_argument("config", help="dataset config (.yaml, .yml or .toml; see examples/dataset_small.yaml)")
    from mitsonar.cli.common import add_output

    add_output(d, "-o", "--output", required=True, reused=True,
               help="dataset folder (created; resumed when it holds this config's dataset)")
    d.add_argument("--workers", type=int, default=None,
                   help="worker processes or Ray actors (default: the cores); 0: render in this process, without "
                        "worker processes (local engine; for debugging and profiling)")
    d.add_argument("--threads", type=int, default=None, help="render threads per worker (default: cores / workers)")
    d.add_argument("--address", default=None, metavar="RAY_ADDRESS",
                   help="run on this Ray cluster: HEAD:PORT of `ray start --head --port PORT` (from a node of the "
                        "cluster), auto, or ray://HEAD:10001 (needs ray[client]); needs mitsonar[cluster]")
    d.add_argument("--engine", choices=("auto", "ray", "local"), default="auto",
                   help="ray: Ray actors (ray.init() on this machine unless --address); local: spawned processes; "
                        "auto (default): Ray when --address is given, else local processes")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_dataset)
