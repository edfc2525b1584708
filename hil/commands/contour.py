"""``python -m hil contour``: the circular test (ISO 230-4) offline on two simulated axes."""

from __future__ import annotations

import argparse
import json

from bridge.contour import CircularTest, Direction
from bridge.contour.figures import PolarPanel, available, polar_figure
from bridge.errors import ContourError
from cmdline import cli
from plant_sim.fmu.arguments import AxisSource, axis_source
from virtual_bus.atomic import replacing

NAME = "contour"
HELP = "the circular test (ISO 230-4) on two simulated axes, offline: a ballbar report"
DESCRIPTION = (
    "Two axes -- two instances of an FMU (--x-param, --y-param) or the compiled kernel of "
    "two axis files (--x-axis, --y-axis) -- interpolate a circle through the "
    "bridge's position cycle (regulator.cycle, the one composition the bridge runs), in both "
    "directions; the report gives ISO 230-4's circular deviations and a ballbar's "
    "decomposition (reversal spikes, backlash per axis, servo and scale mismatch, "
    "squareness), docs/contour.md. Everything is checked before an axis moves: a circle "
    "outside the travel limits, a feed above an axis's limits or node IDs that collide are "
    "one line and exit 2."
)
_MM = 1e-3


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected two numbers A,B") from None
    return a, b


def _travel(text: str) -> tuple[float, float]:
    lo, hi = _pair(text)
    if not lo < hi:
        raise argparse.ArgumentTypeError(f"{text!r}: expected MIN,MAX with MIN < MAX (mm)")
    return lo * _MM, hi * _MM


def _nodes(text: str) -> tuple[int, int]:
    words = text.split(",")
    if len(words) != 2:
        raise argparse.ArgumentTypeError(f"{text!r}: expected two node IDs X,Y (1..127)")
    return cli.node_id(words[0]), cli.node_id(words[1])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fmu",
        type=cli.existing_file,
        help="the axes' FMU (one instance per axis); without it the axis files' compiled kernel",
    )
    for name in ("x", "y"):
        parser.add_argument(
            f"--{name}-param",
            metavar="NAME=VALUE,...",
            help=f"with --fmu: the {name.upper()} axis's FMU parameters, e.g. seed=1008,family=1",
        )
        parser.add_argument(
            f"--{name}-axis",
            type=cli.existing_file,
            metavar="AXIS.toml",
            help=f"the {name.upper()} axis file (with --fmu default: its data sheet)",
        )
        parser.add_argument(
            f"--{name}-travel-mm",
            type=_travel,
            metavar="MIN,MAX",
            help=f"the {name.upper()} axis's travel limits in mm (default: the bridge's 2014h)",
        )
    parser.add_argument("--radius-mm", type=cli.positive_float, default=10.0)
    parser.add_argument("--feed-mm-min", type=cli.positive_float, default=1000.0)
    parser.add_argument(
        "--centre-mm", type=_pair, default=(0.0, 0.0), metavar="X,Y", help="default 0,0"
    )
    parser.add_argument(
        "--direction", choices=("both", "ccw", "cw"), default="both", help="default both"
    )
    parser.add_argument(
        "--control",
        choices=("ordinary", "regulator", "shared", "compensation", "all"),
        default="ordinary",
        help="ordinary (eq. 7), regulator on X alone, shared lambda, backlash compensation "
        "(of the backlash an ordinary test measures first), or all four (default ordinary)",
    )
    parser.add_argument(
        "--kv", type=cli.positive_float, help="k_v of both axes (default: the smaller data sheet's)"
    )
    parser.add_argument(
        "--kv-y-ratio",
        type=cli.bounded_float(0.2, 5.0),
        default=1.0,
        help="Y's k_v over X's (1: matched, eq. 1; 1.1: a 10 %% servo mismatch)",
    )
    parser.add_argument(
        "--beta-t",
        type=cli.positive_float,
        help="the regulator's threshold beta_T in rad/s (eq. 15; default the bridge's 2011h)",
    )
    parser.add_argument(
        "--nodes",
        type=_nodes,
        default=(2, 3),
        metavar="X,Y",
        help="the drives' node IDs (default 2,3; the bridge is node 1)",
    )
    cli.add_output_dir(parser, "report directory")
    parser.add_argument("--figure", type=cli.new_file, help="also the polar plot here (PNG)")


def _source(args: argparse.Namespace, name: str) -> AxisSource:
    """One axis: an FMU instance (``--fmu`` with ``--NAME-param``, the data sheet or
    ``--NAME-axis``) or the compiled kernel of ``--NAME-axis``."""
    params = getattr(args, f"{name}_param")
    axis_path = getattr(args, f"{name}_axis")
    if args.fmu is None:
        if params is not None:
            raise cli.UsageError(f"--{name}-param needs --fmu FMU")
        if axis_path is None:
            raise cli.UsageError(f"give --{name}-axis AXIS.toml, or --fmu FMU --{name}-param ...")
        return axis_source(argparse.Namespace(fmu=None, fmu_param=[], fmu_map=[]), axis_path)
    if params is None:
        raise cli.UsageError(f"--fmu needs --{name}-param NAME=VALUE,... (e.g. seed=1008,family=1)")
    ns = argparse.Namespace(fmu=args.fmu, fmu_param=[params], fmu_map=[])
    return axis_source(ns, axis_path)


def run(args: argparse.Namespace) -> int:
    from ..contour import ContourSetup, Control, check, circular_test, compare

    sources = [_source(args, "x"), _source(args, "y")]
    setup0 = ContourSetup.of(sources, node_ids=args.nodes)
    kv = args.kv or setup0.kv[0]
    setup = ContourSetup.of(
        sources,
        kv=(kv, kv * args.kv_y_ratio),
        node_ids=args.nodes,
        travel=(args.x_travel_mm, args.y_travel_mm),
        beta_t_rad_s=args.beta_t,
    )
    test = CircularTest(
        args.radius_mm * _MM,
        args.feed_mm_min * _MM / 60.0,
        (args.centre_mm[0] * _MM, args.centre_mm[1] * _MM),
    )
    directions = {
        "both": (Direction.CCW, Direction.CW),
        "ccw": (Direction.CCW,),
        "cw": (Direction.CW,),
    }[args.direction]
    check(setup, test, directions)  # everything refused before an axis moves
    if args.control == "all":
        if len(directions) != 2:
            raise ContourError("--control all needs --direction both")
        runs = compare(setup, test)
    elif args.control == "compensation":
        ordinary = circular_test(setup, test, Control.ORDINARY, directions)
        runs = {
            Control.COMPENSATION: circular_test(
                setup, test, Control.COMPENSATION, directions, dict(ordinary.report.backlash)
            )
        }
    else:
        control = Control(args.control)
        runs = {control: circular_test(setup, test, control, directions)}
    args.out.mkdir(parents=True, exist_ok=True)
    summary = {
        "axes": {
            "X": sources[0].name,
            "Y": sources[1].name,
            "kv_per_s": list(setup.kv),
            "nodes": list(args.nodes),
        },
        "controls": {c.value: r.report.summary() for c, r in runs.items()},
    }
    with replacing(args.out / "report.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    text = []
    for c, r in runs.items():
        text += [f"{c.title}:", *r.report.lines(), ""]
    with replacing(args.out / "report.txt") as tmp:
        tmp.write_text("\n".join(text))
    print("\n".join(text).rstrip())
    if args.figure is not None:
        if not available():
            print(f"{args.figure}: not drawn (matplotlib is not installed)")
        else:
            panels = [PolarPanel(c.title, test, r.paths, r.report) for c, r in runs.items()]
            polar_figure(panels, args.figure)
            print(f"polar plot: {args.figure}")
    return 0
