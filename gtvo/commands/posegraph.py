"""``gtvo posegraph FILE``: optimise a pose-graph file and report GTSAM's error and SE-Sync's objective."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gtvo import posegraph as pg
from gtvo.core.paths import check_not_an_input
from gtvo.core.atomic import check_output_file
from gtvo.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``posegraph`` subcommand."""
    p = subparsers.add_parser(
        "posegraph", help="optimise a pose graph (g2o, TORO .graph, iSAM text)",
        description="Optimise a 2-D/3-D pose graph with GTSAM or the hand-rolled Gauss-Newton/LM; print "
                    "GTSAM's error, SE-Sync's objective, iterations and seconds.")
    p.add_argument("file", help="pose-graph file (.g2o, TORO .graph, iSAM .txt)")
    p.add_argument("--format", choices=("auto", "g2o", "toro", "isam"), default="auto",
                   help="file format (default: from the tags)")
    p.add_argument("--solver", choices=pg.SOLVERS, default="gtsam",
                   help="gtsam (default): GTSAM's C++ optimisers; handrolled: the notes' GN / LM in numpy / scipy")
    p.add_argument("--method", choices=pg.METHODS, default="lm",
                   help="lm, gn, or dogleg (gtsam only); default lm")
    p.add_argument("--init", choices=pg.INITS, default="chordal",
                   help="initial poses: file vertices, odometry spanning tree, chordal (LAGO / InitializePose3; "
                        "odometry when GTSAM gives up on it, with a warning); default chordal")
    p.add_argument("--objective", choices=pg.OBJECTIVES, default="geodesic",
                   help="geodesic: GTSAM's BetweenFactor error; sesync: SE-Sync's chordal objective; "
                        "default geodesic")
    p.add_argument("--strict", action="store_true",
                   help="refuse information matrices that are not positive definite (by default the geodesic "
                        "objective replaces each by the nearest positive-definite one, with a warning)")
    p.add_argument("--max-iterations", type=int, default=100, help="iteration limit (default 100)")
    p.add_argument("--out", help="write the optimised graph as g2o (full precision)")
    p.add_argument("--plot", help="write a PNG of the optimised graph")
    p.add_argument("--covariances", metavar="FILE.npz",
                   help="write every node's marginal covariance at the optimum (gtsam.Marginals; GTSAM's tangent "
                        "order, relative to node 0) as .npz")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (the hand-rolled solver shows one)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read, optimise, report, write."""
    for flag, path in (("--out", args.out), ("--plot", args.plot), ("--covariances", args.covariances)):
        if path:
            check_not_an_input(path, {"pose-graph file": args.file}, flag)
            check_output_file(path)
    if args.max_iterations < 1:
        raise InputError(f"--max-iterations must be >= 1, got {args.max_iterations}")
    graph = pg.read(args.file, args.format)
    progress = None
    if args.solver == "handrolled" and not (args.json or args.no_progress):
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=args.max_iterations, desc="handrolled", unit="it", file=sys.stderr, leave=False)

        def progress(it: int, cost: float) -> None:
            bar.update(1)
            bar.set_postfix(cost=f"{cost:.6g}")
    def warn(msg: str) -> None:
        if progress is not None:
            bar.clear()
        print(f"warning: {msg}", file=sys.stderr)

    try:
        result = pg.optimize(graph, solver=args.solver, init=args.init, objective=args.objective,
                             method=args.method, max_iterations=args.max_iterations, progress=progress,
                             strict=args.strict, warn=warn)
    finally:
        if progress is not None:
            bar.close()
    if args.out:
        pg.write_g2o(args.out, result.graph)
    if args.plot:
        from gtvo.posegraph.plot import plot_graph  # noqa: PLC0415

        plot_graph(result.graph, args.plot,
                   title=f"{Path(graph.source).name} ({args.solver}, {args.objective}, GTSAM error {result.gtsam_error:.6g})")
    if args.covariances:
        from gtvo.posegraph.covariance import marginal_covariances, write_marginals  # noqa: PLC0415

        write_marginals(args.covariances, result.graph, marginal_covariances(result.graph, args.objective),
                        args.objective)
    info = result.as_dict()
    info["skipped_lines"] = graph.skipped
    info["identity_information_edges"] = graph.identity_information
    if args.json:
        print(json.dumps(info, allow_nan=False))
    else:
        print(f"{graph.source}: {graph.dim}-D, {graph.num_poses} poses, {graph.num_edges} edges")
        init = args.init if result.init_used == args.init else f"{result.init_used} (--init {args.init} failed)"
        print(f"solver {args.solver} ({args.method}), init {init}, objective {args.objective}")
        print(f"gtsam_error       {result.gtsam_error:.10g}  (initial {result.initial_gtsam_error:.10g})")
        print(f"sesync_objective  {result.sesync_objective:.10g}  (initial {result.initial_sesync_objective:.10g})")
        print(f"iterations        {result.iterations}"
              + ("" if result.converged else f"  (not converged after {result.iterations} iteration{'' if result.iterations == 1 else 's'})"))
        print(f"seconds           {result.seconds:.3f}  (initialisation {result.init_seconds:.3f})")
    return 0
