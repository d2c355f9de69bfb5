"""`navsvc`: simulate drives, replay them through fusion and matching, evaluate the result,
match whole traces, and serve the HTTP + WebSocket API.

Errors print one line naming the file (and line) and the problem, and exit with status 1;
usage errors exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from navsvc import __version__
from navsvc.errors import ConfigError, NavsvcError

if TYPE_CHECKING:
    from navsvc.sim.evaluate import Evaluation
    from navsvc.sim.gnss_replay import GnssErrorRecording

# Imports are lazy: each command imports what it uses, so that `--help`, `--version` and the
# light commands start without NumPy, numba, networkx or FastAPI (they took ~1-4 s).
log = logging.getLogger("navsvc")

# The values of navsvc.fusion's SensorConfig, GpsMode and navsvc.sim's SENSOR_KINDS, written
# out so that building the parser imports neither (tests/cli/test_startup.py checks they agree)
SENSOR_CHOICES = ["gyro_odometer", "steering_odometer", "gyro_accel", "gyro_two_accels",
                  "gps_only", "strapdown"]
FUSION_CHOICES = ["ekf", "rules", "fuzzy"]
SIMULATE_SENSOR_CHOICES = ["all", *SENSOR_CHOICES]
HMM_SIGMA_M = 10.0  # HmmConfig.sigma_m
URBANNAV_DIR = Path(__file__).resolve().parent.parent / "tests" / "data" / "urbannav"


def _outage_arg(text: str) -> tuple[float, float]:
    start, sep, length = text.partition(":")
    try:
        if not sep:
            raise ValueError
        value = float(start), float(length)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"outage {text!r}: expected START:LENGTH in seconds, e.g. 120:60") from None
    if not all(math.isfinite(v) and v >= 0 for v in value) or value[1] == 0:
        raise argparse.ArgumentTypeError(
            f"outage {text!r}: START must be >= 0 and LENGTH > 0 seconds")
    return value


def _positive_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number > 0")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="navsvc", description="Map-matching navigation: sensor fusion onto a road graph.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log what happens")
    parser.add_argument("--version", action="version", version=f"navsvc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser("simulate", help="simulate a drive with truth and sensor packets",
                         description="Drive a simulated vehicle along random routes of a "
                         "road-graph database and write its sensor packets and truth records "
                         "(JSON Lines). Deterministic for a seed.")
    sim.add_argument("--map", required=True, type=Path, metavar="DB",
                     help="road-graph database (from `roadgraph import`)")
    sim.add_argument("-o", "--output", required=True, type=Path, metavar="DRIVE.jsonl",
                     help="where to write the drive")
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument("--duration", type=_positive_arg, default=600.0, metavar="S",
                     help="length of the drive in seconds (default 600)")
    sim.add_argument("--outage", type=_outage_arg, action="append", default=[],
                     metavar="START:LENGTH",
                     help="no GPS from START for LENGTH seconds (repeatable); tunnels on the "
                     "map also block GPS")
    sim.add_argument("--sensors", choices=SIMULATE_SENSOR_CHOICES, default="all",
                     help="which sensors the vehicle has: a sensor configuration, or all of "
                     "them (default all)")
    sim.add_argument("--profile", choices=["default", "harsh-urban"], default="default",
                     help="sensor error levels: default (the fixed levels of SensorErrors) or "
                     "harsh-urban (levels drawn from the seed: GPS correlated error up to 8 m, "
                     "NLOS runs of 20-80 m for 10-60 s, course noise growing as speed falls, "
                     "fixes at 1-10 Hz and 0.1-0.2 s late, gyro bias up to 1 deg/s and scale "
                     "error up to 3 %%, odometer scale error up to 5 %%, speed-only odometers, "
                     "a standstill at the start, a car 1-3.5 m off the map's centre line in "
                     "its lane); default: default")
    sim.add_argument("--gps-error", choices=["synthetic", "urbannav"], default="synthetic",
                     help="GPS position error: synthetic (the profile's model) or urbannav "
                     "(real urban-canyon error of a receiver in Hong Kong, fix minus truth, "
                     "replayed from a seed-chosen second, its gaps as outages; "
                     "tests/data/urbannav); default: synthetic")
    sim.add_argument("--json", action="store_true", help="print a summary as JSON")

    run = sub.add_parser("run", help="replay a drive through fusion and matching",
                         description="Replay sensor packets through the same fusion and "
                         "matching code as a live session; write one matched position per "
                         "GPS epoch (and each second in outages). Truth records are ignored; "
                         "rejected packets are counted and reported with their line.")
    run.add_argument("--map", required=True, type=Path, metavar="DB",
                     help="road-graph database")
    run.add_argument("-i", "--input", required=True, type=Path, metavar="DRIVE.jsonl",
                     help="sensor packets (JSON Lines)")
    run.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.jsonl",
                     help="where to write matched positions")
    _add_session_options(run, epilog=MODES_HELP)

    ev = sub.add_parser("evaluate", help="accuracy of a run against the truth of its drive",
                        description="Position error (RMS, 95%, max) of the output and of "
                        "the fusion alone beside raw GPS, drift in each GPS outage, heading "
                        "error, share of epochs on the right road, intersections traversed "
                        "correctly.")
    ev.add_argument("--truth", required=True, type=Path, metavar="DRIVE.jsonl",
                    help="the drive: its GPS packets, and its truth records when it has "
                    "them (a real log without them is plotted with --plot, not scored)")
    ev.add_argument("--estimate", required=True, type=Path, metavar="OUT.jsonl",
                    help="matched positions from `navsvc run`")
    ev.add_argument("--json", action="store_true", help="print the metrics as JSON")
    ev.add_argument("--plot", type=Path, metavar="FILE.png",
                    help="also draw raw GPS, fused track, output and truth (PNG)")
    ev.add_argument("--map", type=Path, metavar="DB",
                    help="road-graph database drawn under the plot")
    ev.add_argument("--title", help="the plot's title (default: the run's files, time span "
                    "and headline scores)")

    _add_match_parser(sub)
    _add_tune_parser(sub)

    sv = sub.add_parser("serve", help="run the HTTP + WebSocket service",
                        description="Serve the API of interfaces.md (prefix /v1; OpenAPI at "
                        "/openapi.json, docs at /docs) on one road-graph database. Sessions "
                        "open when the server stopped are restored from the trip log. Limits "
                        "and API keys come from NAVSVC_* environment variables (README).")
    sv.add_argument("--map", type=Path, metavar="DB",
                    help="road-graph database (default: $NAVSVC_MAP)")
    sv.add_argument("--host", default=os.environ.get("NAVSVC_HOST", "127.0.0.1"),
                    help="address to listen on (default: $NAVSVC_HOST or 127.0.0.1)")
    sv.add_argument("--port", type=int, default=int(os.environ.get("NAVSVC_PORT", "8000")),
                    help="TCP port (default: $NAVSVC_PORT or 8000)")
    sv.add_argument("--triplog", type=Path, metavar="FILE",
                    help="trip log SQLite file (default: $NAVSVC_TRIPLOG, else DB's stem + "
                    ".trips.db beside DB)")
    sv.add_argument("--warm-up-only", action="store_true",
                    help="compile the filter kernels into numba's cache and exit (the Docker "
                    "build does this, so that a container starts in seconds)")
    sv.add_argument("--profiles", type=Path, metavar="DIR",
                    help="a folder of tuned profiles (`navsvc tune`); a session names one by "
                    "its file stem (default: $NAVSVC_PROFILES)")
    sv.add_argument("--stream-port", type=_whole_number_arg(1, 65535), metavar="PORT",
                    default=os.environ.get("NAVSVC_STREAM_PORT") or None,
                    help="also serve the session stream (WS /v1/sessions/{id}/stream, the "
                    "same protocol) on picows on --host:PORT, at less CPU per message than "
                    "uvicorn's (default: $NAVSVC_STREAM_PORT, else not)")
    _add_worker_options(sv)

    sd = sub.add_parser("send", help="stream a drive to a running service",
                        description="Create a session on a running `navsvc serve`, stream the "
                        "packets of a drive file over its WebSocket (truth records stay "
                        "behind), and write the matched positions it answers with (JSON "
                        "Lines, the same as `navsvc run`, so `navsvc evaluate` reads them).")
    sd.add_argument("input", type=Path, metavar="DRIVE.jsonl", help="sensor packets")
    sd.add_argument("--url", default="http://127.0.0.1:8000",
                    help="the service (default http://127.0.0.1:8000)")
    sd.add_argument("-o", "--output", type=Path, metavar="OUT.jsonl",
                    help="where to write matched positions (default: only a summary)")
    sd.add_argument("--vehicle-id", default="navsvc-send", help="the session's vehicle id")
    sd.add_argument("--batch", type=_whole_number_arg(1, MAX_BATCH), default=10,
                    help=f"packets per message, 1 to {MAX_BATCH} (default 10)")
    sd.add_argument("--keep", action="store_true",
                    help="leave the session open at the end (default: close it, which drops "
                    "its trip log on the server)")
    sd.add_argument("--realtime", action="store_true",
                    help="send at the drive's own pace instead of as fast as possible")
    sd.add_argument("--api-key", default=os.environ.get("NAVSVC_API_KEY"),
                    help="API key (default: $NAVSVC_API_KEY)")
    _add_session_options(sd, epilog=MODES_HELP,
                         sensors_note="; packets of sensors it does not use stay behind")

    vw = sub.add_parser("view", help="show a drive or a run on the map page",
                        description="Open the map page on a finished drive (sensor packets: "
                        "replayed through fusion and matching as `navsvc run` does, raw fixes "
                        "and matched positions drawn) or a run (matched positions from `navsvc "
                        "run` or `navsvc send -o`), served by a local navsvc server until "
                        "Ctrl-C. A slider and Play go through it in time.")
    vw.add_argument("input", type=Path, metavar="DRIVE.jsonl|OUT.jsonl",
                    help="a drive or a run (JSON Lines)")
    vw.add_argument("--map", type=Path, metavar="DB",
                    help="road-graph database (default: $NAVSVC_MAP)")
    vw.add_argument("--truth", action="store_true",
                    help="draw the truth track too (a drive's kind truth records)")
    vw.add_argument("--sensors", choices=SENSOR_CHOICES, default="gyro_odometer",
                    help="for a drive: the sensor configuration to replay it with (default "
                    "gyro_odometer)")
    vw.add_argument("--fusion", choices=FUSION_CHOICES, default="ekf",
                    help="for a drive: GPS fusion mode (default ekf)")
    vw.add_argument("--host", default="127.0.0.1", help="address to listen on (default "
                    "127.0.0.1)")
    vw.add_argument("--port", type=int, default=8001, help="TCP port (default 8001)")
    vw.add_argument("--no-browser", action="store_true",
                    help="do not open a web browser, only print the address")
    vw.epilog = MODES_HELP
    _add_verbose_everywhere(sub)
    return parser


def _add_worker_options(sv: argparse.ArgumentParser) -> None:
    """`serve`'s options for several workers behind HAProxy (navsvc.cluster)."""
    sv.add_argument("--workers", type=_whole_number_arg(1, 64),
                    default=os.environ.get("NAVSVC_WORKERS", "1"), metavar="N",
                    help="worker processes, each with its own sessions and trip log "
                    "(<triplog>.w<k>), behind HAProxy on --host:--port, which routes on the "
                    "session id; a worker that dies is started again and restores its "
                    "sessions (default: $NAVSVC_WORKERS or 1: one process, no balancer)")
    sv.add_argument("--balancer", action="store_true",
                    help="HAProxy in front even of one worker")
    sv.add_argument("--worker-port-base", type=int, metavar="PORT",
                    help="worker k listens on 127.0.0.1:PORT+k (default: --port + 1), and "
                    "with --stream-port its picows stream on PORT+N+k")
    sv.add_argument("--worker-id", type=int, metavar="K",
                    help="serve as worker K of a fleet behind a balancer: session ids "
                    "w<K>-..., trip log <triplog>.w<K> (default: $NAVSVC_WORKER_ID; "
                    "--workers N sets it for its workers)")


def _whole_number_arg(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: a whole number from ``low`` to ``high``, else a message saying so."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text}: must be from {low} to {high}")
        return value
    return parse


MAX_BATCH = 1000  # the service's default NAVSVC_MAX_BATCH_PACKETS
MODES_HELP = (
    "Sensor configurations: gyro_odometer (yaw-rate gyro and wheel odometer; the seed thesis's "
    "choice), steering_odometer (steering angle and odometer, bicycle model), gyro_accel (gyro "
    "and forward accelerometer), gyro_two_accels (gyro, forward and lateral accelerometers), "
    "gps_only (GPS alone, constant turn rate and velocity), strapdown (a full 6-axis IMU: "
    "strapdown INS/GNSS). GPS fusion modes: ekf (Kalman update, gated and adaptive), rules "
    "(the thesis's rule-based weighting), fuzzy (the thesis's fuzzy weighting).")


def _add_verbose_everywhere(sub: Any) -> None:
    """`-v` after the subcommand too (`navsvc run -v ...`), not only before it."""
    for parser in sub.choices.values():
        if not any("--verbose" in a.option_strings for a in parser._actions):
            parser.add_argument("-v", "--verbose", action="store_true",
                                default=argparse.SUPPRESS, help="log what happens")


def _add_session_options(parser: argparse.ArgumentParser, epilog: str | None = None,
                         sensors_note: str = "") -> None:
    """The session settings and output switches that `run` and `send` share."""
    parser.epilog = epilog
    parser.add_argument("--sensors", choices=SENSOR_CHOICES, default="gyro_odometer",
                        help=f"sensor configuration (default gyro_odometer{sensors_note}; "
                        "see below)")
    parser.add_argument("--fusion", choices=FUSION_CHOICES, default="ekf",
                        help="GPS fusion mode (default ekf; see below)")
    parser.add_argument("--map-feedback", action=argparse.BooleanOptionalAction,
                        default=None,
                        help="feed confident matches back into the filter as a road "
                        "constraint (bounds drift in GPS outages; default: on)")
    parser.add_argument("--profile", type=Path, metavar="PROFILE.json",
                        help="tuned parameters for the session (from `navsvc tune`)")
    parser.add_argument("--json", action="store_true", help="print a summary as JSON")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _profile_option(args: argparse.Namespace) -> dict[str, Any]:
    """The session option of ``--profile`` (its parameters inline), or nothing."""
    if args.profile is None:
        return {}
    from navsvc.tuning.profile import read_profile

    return {"profile": {"name": args.profile.stem,
                        "parameters": read_profile(args.profile)["parameters"]}}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(_COMMANDS[args.command](args))
    except Exception as exc:
        if not isinstance(exc, _expected_errors()):
            raise
        print(f"navsvc: error: {exc}", file=sys.stderr)
        return 1


def _expected_errors() -> tuple[type[Exception], ...]:
    """NavsvcError, and RoadGraphError when roadgraph was imported (else none was raised)."""
    roadgraph_errors = sys.modules.get("roadgraph.errors")
    if roadgraph_errors is None:
        return (NavsvcError,)
    return NavsvcError, roadgraph_errors.RoadGraphError


def _cmd_simulate(args: argparse.Namespace) -> int:
    from navsvc.sim.harsh import harsh_urban_spec
    from navsvc.sim.simulate import SENSOR_KINDS, DriveSpec, simulate_drive
    from navsvc.wire.jsonl import write_records
    from roadgraph import RoadGraph

    graph = RoadGraph.open(args.map)
    spec = DriveSpec(duration_s=args.duration, seed=args.seed, outages=tuple(args.outage),
                     sensors=SENSOR_KINDS[args.sensors], full_imu=args.sensors == "strapdown",
                     gps_error_replay=_urbannav() if args.gps_error == "urbannav" else None)
    if args.profile == "harsh-urban":
        spec = harsh_urban_spec(spec)
    records = simulate_drive(graph, spec)
    count = write_records(args.output, records)
    kinds = Counter(r["kind"] for r in records)
    log.info("wrote %d records to %s", count, args.output)
    summary = {"output": str(args.output), "records": count, "by_kind": dict(kinds),
               "duration_s": args.duration, "seed": args.seed}
    print(json.dumps(summary) if args.json else
          f"{args.output}: {count} records ({', '.join(f'{k} {n}' for k, n in kinds.items())})")
    return 0


def _urbannav() -> GnssErrorRecording:
    from navsvc.sim.gnss_replay import parse_urbannav

    spp, truth = URBANNAV_DIR / "spp_fixes.csv", URBANNAV_DIR / "groundTruth_TST.csv"
    try:
        return parse_urbannav(spp.read_text(), truth.read_text())
    except OSError as exc:
        raise ConfigError(f"{exc.filename}: cannot read the UrbanNav recording "
                          f"({exc.strerror})") from None


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from navsvc.errors import Rejection, RejectReason
    from navsvc.session import VehicleSession, config_from_options
    from navsvc.wire.jsonl import iter_lines, write_records
    from navsvc.wire.positions import position_json
    from roadgraph import RoadGraph

    graph = RoadGraph.open(args.map)
    try:
        config = config_from_options({"sensors": args.sensors, "fusion": args.fusion,
                                      "map_feedback": args.map_feedback,
                                      **_profile_option(args)})
    except ConfigError as exc:
        print(f"navsvc: error: {exc}", file=sys.stderr)
        return 2
    session = VehicleSession(config, graph)
    lines = list(iter_lines(args.input))
    positions: list[dict[str, Any]] = []
    rejections: list[tuple[int, Rejection]] = []
    frame = graph.frame
    for line in tqdm(lines, desc="replay", unit="pkt", disable=args.quiet, leave=False):
        if line.error is not None:
            rejections.append((line.number, Rejection(line.number, RejectReason.MALFORMED,
                                                      line.error)))
            continue
        result = session.add_records([line.value], first_index=line.number)
        rejections += [(line.number, r) for r in result.rejections]
        positions += [position_json(p, frame) for p in result.positions]
    write_records(args.output, positions)
    for number, r in rejections[5:20]:  # the first 5 are printed below
        log.info("%s:%d: %s: %s", args.input, number, r.reason.code, r.detail)
    by_reason = Counter(r.reason.code for _, r in rejections)
    summary = {"input": str(args.input), "output": str(args.output), "packets": len(lines),
               "positions": len(positions), "rejected": sum(by_reason.values()),
               "rejected_by_reason": dict(by_reason)}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{args.output}: {len(positions)} positions from {len(lines)} packets; "
              f"{summary['rejected']} rejected"
              + (f" ({', '.join(f'{k} {n}' for k, n in by_reason.items())})" if by_reason
                 else ""))
        for number, r in rejections[:5]:
            print(f"  {args.input}:{number}: {r.reason.code}: {r.detail}")
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from navsvc.sim.evaluate import evaluate
    from navsvc.wire.jsonl import read_records
    from roadgraph import RoadGraph

    drive = read_records(args.truth)
    estimates = read_records(args.estimate)
    has_truth = any(r.get("kind") == "truth" for r in drive)
    if not has_truth and args.plot is None:
        raise NavsvcError(f"{args.truth}: the drive has no truth records (nothing to score; "
                          "--plot draws it without)")
    result = None
    if has_truth:
        try:
            result = evaluate(drive, estimates)
        except ValueError as exc:
            raise NavsvcError(f"{args.truth}: {exc}") from None
        except KeyError as exc:
            raise NavsvcError(f"{args.estimate}: a record lacks the field {exc}") from None
    if args.plot is not None:
        from navsvc.sim.plot import plot_run  # matplotlib is slow to import

        graph = RoadGraph.open(args.map) if args.map is not None else None
        title = args.title or _plot_title(args, estimates, result)
        plot_run(drive, estimates, args.plot, graph=graph, title=title)
    if result is None:
        print(f"{args.truth}: no truth records; plotted to {args.plot}, not scored")
        return 0
    print(json.dumps(result.to_json(), indent=2) if args.json else format_evaluation(result))
    return 0


def _plot_title(args: argparse.Namespace, estimates: list[dict[str, Any]],
                result: Evaluation | None) -> str:
    """The run's files, time span and, with truth, its headline scores."""
    times = [r["t"] for r in estimates if isinstance(r.get("t"), (int, float))]
    span = f", {max(times) - min(times):.0f} s" if times else ""
    title = f"{args.estimate.name} on {args.truth.name}{span}, {len(estimates)} positions"
    if result is not None:
        title += (f"\nfused/raw GPS RMS {result.fused_to_raw_ratio:.2f}, right road "
                  f"{100.0 * (result.on_right_road_share or 0.0):.0f} %")
    return title


def format_evaluation(e: Evaluation) -> str:
    """A plain-text table of the metrics."""
    def row(name: str, s: Any) -> str:
        return f"{name:<22}{s.rms_m:>9.2f}{s.p95_m:>9.2f}{s.max_m:>9.2f}{s.n:>8d}"

    lines = [f"{'error (m)':<22}{'RMS':>9}{'95%':>9}{'max':>9}{'n':>8}",
             row("output position", e.position), row("fused (unconstrained)", e.fused),
             row("raw GPS", e.raw_gps),
             row("fused at GPS epochs", e.fused_at_gps),
             f"fused / raw GPS RMS at the same epochs: {e.fused_to_raw_ratio:.2f}",
             f"heading error: RMS {e.heading_rms_deg:.2f} deg, 95% {e.heading_p95_deg:.2f} deg"]
    for o in e.outages:
        lines.append(f"GPS outage {o.start_s:.0f}-{o.end_s:.0f} s: {o.distance_m:.0f} m driven, "
                     f"error at end {o.end_error_m:.1f} m ({o.drift_pct:.2f} %), "
                     f"max {o.max_error_m:.1f} m")
    if e.on_right_road_share is None:
        lines.append("road matching: no epoch was matched to a road")
    else:
        lines.append(f"on the right road: {100 * e.on_right_road_share:.1f} % of epochs; "
                     f"intersections correct: {e.intersections_correct}/"
                     f"{e.intersections_total}")
    return "\n".join(lines)


# --- match: one trace or a batch, in process or on Dask (issue 19) ---------------------------

def _add_match_parser(sub: Any) -> None:
    mt = sub.add_parser("match", help="match GPS traces to routes (offline, one or a batch)",
                        description="Hidden-Markov-model matching (Newson & Krumm 2009) of "
                        "GPX, GeoJSON, CSV or JSON Lines traces. Points are sorted by time and "
                        "exact duplicates dropped; a gap the road graph cannot bridge starts a "
                        "new route segment. One trace file: its route JSON to stdout or -o. "
                        "Several (files, folders, globs): one STEM.route.json each in "
                        "--out-dir and a summary; a bad trace is reported with its file and "
                        "line and the others go on (exit status 1 if any failed).")
    mt.add_argument("trace", nargs="+", metavar="TRACE",
                    help="trace files (.gpx, .geojson/.json, .csv, .jsonl), folders or globs")
    mt.add_argument("--map", required=True, type=Path, metavar="DB", help="road-graph database")
    mt.add_argument("-o", "--output", type=Path, metavar="ROUTE.json",
                    help="one trace: write the route JSON here (default: stdout)")
    mt.add_argument("--out-dir", type=Path, metavar="DIR",
                    help="a batch: write the routes here (default: the current folder)")
    mt.add_argument("--sigma", type=_positive_arg, default=HMM_SIGMA_M, metavar="M",
                    help=f"GPS error in metres (default {HMM_SIGMA_M:g})")
    mt.add_argument("--json", action="store_true",
                    help="one trace: print the whole route JSON even with -o; a batch: print "
                    "the summary as JSON")
    mt.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_cluster_options(mt)


def _add_cluster_options(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, nargs="?", const=-1, default=None, metavar="N",
                       help="run on a local Dask cluster of N processes on 127.0.0.1 (N "
                       "omitted: one per core); default: in this process")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on an existing Dask cluster (e.g. tcp://10.0.0.5:8786)")


def _executor(args: argparse.Namespace) -> Any:
    from navsvc.batch import executor

    if args.scheduler is not None:
        return executor(scheduler=args.scheduler)
    if args.workers is None:
        return executor(0)
    return executor(None if args.workers == -1 else args.workers)


def _cmd_match(args: argparse.Namespace) -> int:
    from navsvc.batch import expand_traces

    single = len(args.trace) == 1 and Path(args.trace[0]).is_file() and args.out_dir is None
    if single and args.workers is None and args.scheduler is None:
        return _match_one(args, Path(args.trace[0]))
    if args.output is not None:
        print("navsvc: error: -o names one route file; for several traces use --out-dir",
              file=sys.stderr)
        return 2
    return _match_batch(args, expand_traces(args.trace))


def _match_one(args: argparse.Namespace, trace: Path) -> int:
    from navsvc.matching.hmm import HmmConfig
    from navsvc.wire.route import match_trace
    from navsvc.wire.traces import read_trace
    from roadgraph import RoadGraph

    graph = RoadGraph.open(args.map)
    fixes = read_trace(trace)
    route = match_trace(graph, fixes, HmmConfig(sigma_m=args.sigma, beta_m=2.0 * args.sigma))
    text = json.dumps(route, ensure_ascii=False)
    if args.output is None or args.json:
        print(text)
    if args.output is not None:
        try:
            args.output.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise NavsvcError(f"{args.output}: cannot write ({exc.strerror})") from None
        if not args.json:
            streets = [s for seg in route["segments"] for s in seg["streets"] if s]
            print(f"{args.output}: {len(route['segments'])} segment(s), "
                  f"{route['length_m']:.0f} m; streets: {', '.join(streets) or '-'}")
    return 0


def _match_batch(args: argparse.Namespace, traces: list[Path]) -> int:
    import time

    from tqdm import tqdm

    from navsvc.batch import chunks, match_files, open_map, output_paths
    from navsvc.matching.hmm import HmmConfig
    from roadgraph import RoadGraph

    RoadGraph.open(args.map)  # a wrong map fails here, once
    folder = args.out_dir or Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise NavsvcError(f"{folder}: cannot create ({exc.strerror})") from None
    config = HmmConfig(sigma_m=args.sigma, beta_m=2.0 * args.sigma)
    jobs = [(str(t), str(o)) for t, o in zip(traces, output_paths(traces, folder))]
    started = time.perf_counter()
    summaries: list[Any] = []
    with _executor(args) as pool, tqdm(total=len(jobs), desc="match", unit="trace",
                                       disable=args.quiet, leave=False) as bar:
        pool.warm_up(open_map, str(args.map.resolve()))
        parts = chunks(jobs, pool.workers if pool.distributed else 0)
        done: list[Any] = [None] * len(parts)
        tasks = [(str(args.map.resolve()), part, config) for part in parts]
        for i, found in pool.run(match_files, tasks):
            done[i] = found
            bar.update(len(found))
        summaries = [s for part in done for s in part]
        where, workers = pool.where, pool.workers
    wall_s = time.perf_counter() - started
    ok = [s for s in summaries if s.error is None]
    points = sum(s.points for s in ok)
    total = {"traces": len(summaries), "matched": len(ok), "failed": len(summaries) - len(ok),
             "points": points, "length_m": round(sum(s.length_m for s in ok), 1),
             "wall_s": round(wall_s, 3), "points_per_s": round(points / wall_s, 1),
             "where": where, "workers": workers}
    if args.json:
        print(json.dumps({"total": total, "traces": [s.to_json() for s in summaries]}))
    else:
        print(f"{'trace':<40}{'points':>8}{'matched %':>10}{'length m':>10}{'time s':>8}")
        for s in ok:
            print(f"{Path(s.trace).name[:39]:<40}{s.points:>8}{100 * s.matched_share:>10.1f}"
                  f"{s.length_m:>10.0f}{s.time_s:>8.2f}")
        print(f"{len(ok)} of {len(summaries)} traces matched, {points} points in "
              f"{wall_s:.1f} s ({total['points_per_s']:.0f} points/s, {where}); routes in "
              f"{folder}")
    for s in summaries:
        if s.error is not None:
            print(f"navsvc: error: {s.error}", file=sys.stderr)
    return 0 if len(ok) == len(summaries) else 1


# --- tune: hill climbing and a genetic algorithm over the parameter table (issue 19) ------

def _add_tune_parser(sub: Any) -> None:
    tn = sub.add_parser("tune", help="tune fusion and matcher parameters on drives",
                        description="Search the declared parameter table (--list-params) "
                        "by hill climbing or a genetic algorithm (seed thesis 5.6), scoring "
                        "each parameter set by replaying every drive (the code of `navsvc "
                        "run`): with truth records, a weighted score of the right-road share, "
                        "the intersections traversed correctly and the fused error relative "
                        "to raw GPS; a real log without truth against its known --route. "
                        "Writes a profile (the parameters that differ from the defaults, the "
                        "fitness before and after) for `run/send --profile` and `serve "
                        "--profiles`. The run's state is saved after each step "
                        "(PROFILE.state.json unless --resume names it) and --resume "
                        "continues it.")
    tn.add_argument("--map", type=Path, metavar="DB", help="road-graph database")
    tn.add_argument("--drives", nargs="+", type=Path, metavar="DRIVE.jsonl",
                    help="drives to tune on (from `navsvc simulate`, or real logs with "
                    "--route)")
    tn.add_argument("--route", action="append", default=[], metavar="ROUTE",
                    help="per drive, in order: the known route of a drive without truth (a "
                    "GPX, or a file of the OSM way ids driven); '-' for a drive with truth")
    tn.add_argument("--method", choices=["hill", "ga"], default="hill",
                    help="hill climbing (default) or the genetic algorithm")
    tn.add_argument("--budget", type=int, default=40, metavar="N",
                    help="parameter sets to evaluate, each one replay per drive (default 40)")
    tn.add_argument("--params", metavar="NAME,NAME...",
                    help="parameters to tune (default: a useful set; see --list-params)")
    tn.add_argument("--seed", type=int, default=0, help="random seed of the GA (default 0)")
    tn.add_argument("--population", type=int, default=10, metavar="N",
                    help="GA population size (default 10)")
    tn.add_argument("--from", dest="start", type=Path, metavar="PROFILE.json",
                    help="start from this profile instead of the defaults")
    tn.add_argument("--resume", type=Path, metavar="STATE.json",
                    help="continue the run saved here (started anew when missing)")
    tn.add_argument("-o", "--output", type=Path, metavar="PROFILE.json",
                    help="where to write the profile")
    tn.add_argument("--list-params", action="store_true",
                    help="print the parameter table and exit")
    tn.add_argument("--sensors", choices=SENSOR_CHOICES, default="gyro_odometer",
                    help="sensor configuration of the sessions (default gyro_odometer)")
    tn.add_argument("--fusion", choices=FUSION_CHOICES, default="ekf",
                    help="GPS fusion mode of the sessions (default ekf)")
    tn.add_argument("--map-feedback", action=argparse.BooleanOptionalAction, default=None,
                    help="sessions with or without map feedback (default: as a session, on "
                    "where the sensor configuration allows it)")
    tn.add_argument("--json", action="store_true", help="print a summary as JSON")
    tn.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_cluster_options(tn)


def _cmd_tune(args: argparse.Namespace) -> int:
    from navsvc.tuning.params import DEFAULT_SET, TABLE, select

    if args.list_params:
        print(f"{'name':<48}{'component':<15}{'range':<28}{'bits':>4}  default set")
        for p in TABLE:
            print(f"{p.name:<48}{p.component:<15}{p.describe():<28}{p.bits:>4}  "
                  f"{'yes' if p.name in DEFAULT_SET else ''}")
        return 0
    missing = [f for f, v in (("--map", args.map), ("--drives", args.drives),
                              ("-o", args.output)) if not v]
    if missing:
        print(f"navsvc: error: tune needs {', '.join(missing)}", file=sys.stderr)
        return 2
    params = select([n.strip() for n in args.params.split(",") if n.strip()]
                    if args.params else None)
    return _tune(args, params)


def _tune(args: argparse.Namespace, params: Any) -> int:
    from tqdm import tqdm

    from navsvc.batch import open_map
    from navsvc.session import config_from_options
    from navsvc.tuning.inputs import read_drives
    from navsvc.tuning.run import TuneRun, result_profile, save_json, tune
    from roadgraph import RoadGraph

    graph = RoadGraph.open(args.map)
    drives = read_drives(graph, args.drives, args.route)
    options = {"sensors": args.sensors, "fusion": args.fusion,
               "map_feedback": args.map_feedback}
    if args.start is not None:
        from navsvc.tuning.profile import read_profile

        options["profile"] = {"parameters": read_profile(args.start)["parameters"]}
    config_from_options(options)  # a refused combination fails before any replay
    fresh = TuneRun.start(args.method, params, args.seed, args.budget,
                          [d.name for d in drives], options, args.population)
    state_path = args.resume or args.output.with_suffix(".state.json")
    run = fresh
    if args.resume is not None and args.resume.exists():
        try:
            run = TuneRun.from_json(json.loads(args.resume.read_text(encoding="utf-8")))
        except (OSError, ValueError, KeyError) as exc:
            raise ConfigError(f"{args.resume}: not a tuning state ({exc})") from None
        except ConfigError as exc:
            raise ConfigError(f"{args.resume}: {exc}") from None
        run.check_same(fresh)
        run.budget = args.budget
    with _executor(args) as pool, tqdm(total=args.budget * len(drives),
                                       initial=run.evaluations * len(drives),
                                       desc=f"tune {args.method}", unit="replay",
                                       disable=args.quiet, leave=False) as bar:
        def progress(n: int, best: float | None) -> None:
            bar.update(n)
            if best is not None:
                bar.set_postfix(best=f"{best:.4f}")

        pool.warm_up(open_map, str(args.map.resolve()))
        tune(run, pool, str(args.map.resolve()), drives,
             save=lambda r: save_json(state_path, r.to_json()), progress=progress)
        where = pool.where
    profile = result_profile(run)
    save_json(args.output, profile)
    tuned = profile["tuned"]
    summary = {"output": str(args.output), "state": str(state_path), "method": args.method,
               "evaluations": run.evaluations, "replays": tuned["replays"],
               "fitness_before": tuned["fitness_before"],
               "fitness_after": tuned["fitness_after"], "parameters": profile["parameters"],
               "where": where}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{args.output}: fitness {tuned['fitness_before']:.4f} -> "
              f"{tuned['fitness_after']:.4f} on {len(drives)} drive(s), {run.evaluations} "
              f"evaluations ({tuned['replays']} replays, {where}); state in {state_path}")
        for name, value in profile["parameters"].items():
            print(f"  {name} = {value}")
    return 0


def _cmd_send(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from navsvc.sim.simulate import SENSOR_KINDS
    from navsvc.wire.client import close_session, create_session, stream_packets
    from navsvc.wire.jsonl import iter_lines, write_records

    left_behind = {"truth", *SENSOR_KINDS["all"]} - set(SENSOR_KINDS[args.sensors])
    lines = list(iter_lines(args.input))
    bad = [line for line in lines if line.error is not None]
    kept = [line for line in lines if line.error is None
            and not (isinstance(line.value, dict) and line.value.get("kind") in left_behind)]
    packets = [line.value for line in kept]
    options = {"vehicle_id": args.vehicle_id, "sensors": args.sensors, "fusion": args.fusion,
               "map_feedback": args.map_feedback, **_profile_option(args)}
    session_id = create_session(args.url, options, args.api_key)
    with tqdm(total=len(packets), desc="send", unit="pkt", disable=args.quiet,
              leave=False) as bar:
        result = stream_packets(args.url, session_id, packets, batch=args.batch,
                                realtime=args.realtime, api_key=args.api_key,
                                progress=bar.update)
    if not args.keep:
        close_session(args.url, session_id, args.api_key)
    if args.output:
        write_records(args.output, result.positions)
    problems = [(line.number, "malformed", line.error) for line in bad] + \
        [(kept[r["index"]].number, r["code"], r["message"]) for r in result.rejected]
    problems.sort()
    summary = {"session_id": session_id, "packets": len(packets), "accepted": result.accepted,
               "rejected": len(result.rejected), "positions": len(result.positions),
               "unreadable_lines": len(bad), "reconnects": result.reconnects,
               "closed": not args.keep, "output": str(args.output) if args.output else None,
               "rejections": [{"line": n, "code": c, "message": m}
                              for n, c, m in problems[:100]]}
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"session {session_id}: {result.accepted} of {len(packets)} packets accepted, "
          f"{len(result.rejected)} rejected, {len(bad)} unreadable lines, "
          f"{len(result.positions)} positions" + (f" written to {args.output}" if args.output
                                                    else "")
          + ("" if args.keep else "; session closed"))
    for number, code, message in problems[:5]:
        print(f"  {args.input}:{number}: {code}: {message}")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn  # only the service needs it

    from navsvc.api import Settings, create_app

    logging.getLogger("navsvc").setLevel(logging.INFO)  # a service says what it does
    if args.warm_up_only:
        from navsvc.api.warmup import warm_up
        from roadgraph import RoadGraph

        map_path = args.map or os.environ.get("NAVSVC_MAP")
        if not map_path:
            raise ConfigError("no map: pass --map DB or set NAVSVC_MAP")
        warm_up(RoadGraph.open(map_path))
        return 0
    if args.workers > 1 or args.balancer:
        return _serve_workers(args)
    settings = Settings.from_env(map_path=args.map, triplog_path=args.triplog,
                                 profiles_path=args.profiles, worker_id=args.worker_id,
                                 stream_port=args.stream_port, stream_host=args.host)
    log.info("profiles: %s", ", ".join(settings.profiles()) or "none")  # a bad one fails here
    app = create_app(settings)
    if settings.worker_id is not None:  # the balancer's health checks, twice a second
        logging.getLogger("uvicorn.access").addFilter(
            lambda record: "/v1/healthz" not in record.getMessage())
    # no per-message compression: replies are small, and deflate cost more CPU than it saved
    uvicorn.run(app, host=args.host, port=args.port, ws_ping_interval=20.0,
                ws_ping_timeout=20.0, ws_per_message_deflate=False,
                log_level="debug" if args.verbose else "info")
    return 0


def _serve_workers(args: argparse.Namespace) -> int:
    """`serve --workers N`: HAProxy and N workers under a supervisor (navsvc.cluster)."""
    from navsvc.api import Settings
    from navsvc.cluster import ClusterPlan, serve_cluster

    if args.worker_id is not None:
        raise ConfigError("--worker-id is for one worker; --workers N numbers its own")
    settings = Settings.from_env(map_path=args.map, triplog_path=args.triplog,
                                 profiles_path=args.profiles)  # a bad setting fails here
    plan = ClusterPlan.local(args.host, args.port, args.workers, settings.triplog,
                             args.worker_port_base, args.stream_port)
    worker_args = ["--map", str(settings.map_path)]
    if args.profiles is not None:
        worker_args += ["--profiles", str(args.profiles)]
    return serve_cluster(plan, worker_args, verbose=args.verbose)


def _cmd_view(args: argparse.Namespace) -> int:
    import tempfile
    import threading
    import webbrowser

    import uvicorn

    from navsvc.api import Settings, create_app
    from navsvc.web.replay import load_replay
    from roadgraph import RoadGraph

    map_path = args.map or os.environ.get("NAVSVC_MAP")
    if not map_path:
        raise ConfigError("no map: pass --map DB or set NAVSVC_MAP")
    graph = RoadGraph.open(Path(map_path))
    replay = load_replay(args.input, graph, {"sensors": args.sensors, "fusion": args.fusion},
                         with_truth=args.truth)
    for problem in replay["problems"][:5]:
        print(f"  {problem}", file=sys.stderr)
    if args.truth and not replay["truth"]:
        print(f"navsvc: {args.input} has no truth records", file=sys.stderr)
    url = f"http://{args.host}:{args.port}/"
    print(f"{args.input}: {len(replay['fixes'])} fixes, {len(replay['positions'])} positions; "
          f"map view on {url} (Ctrl-C stops)", flush=True)
    with tempfile.TemporaryDirectory(prefix="navsvc-view-") as folder:
        settings = Settings(map_path=Path(map_path), triplog_path=Path(folder) / "trips.db")
        app = create_app(settings, replay=replay)
        if not args.no_browser:
            threading.Timer(1.0, webbrowser.open, [url]).start()
        uvicorn.run(app, host=args.host, port=args.port,
                    log_level="info" if args.verbose else "warning")
    return 0


_COMMANDS = {"simulate": _cmd_simulate, "run": _cmd_run, "evaluate": _cmd_evaluate,
             "match": _cmd_match, "serve": _cmd_serve, "send": _cmd_send, "view": _cmd_view,
             "tune": _cmd_tune}
