"""Command line of the simulator: ``python -m sim {run,linearize,presets}`` (SPEC C2, PROTOCOL.md).

``run`` prints exactly one line ``READY <endpoint>`` on stdout once the endpoint is listening, so a
parent process can wait for it (with the port actually bound: ``--listen udpin:127.0.0.1:0`` lets
the OS choose a free one); SIGINT/SIGTERM end it cleanly (exit code 0). With ``--lockstep`` one last
line ``STATS <json>`` follows at exit (counters and the lockstep record, ``SimServer.summary``: a
parent learns whether the run was exact).
"""
from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
from typing import Sequence


def _current(text: str) -> tuple[float, float]:
    try:
        north, east = (float(part) for part in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError("expected VN,VE in m/s, e.g. 0.1,-0.05") from exc
    return north, east


def _fault(text: str):
    from sim.faults import parse_fault

    try:
        return parse_fault(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: the --listen forms the simulator serves, and what to write instead of the client forms
LISTEN_FORMS = ("udpin", "tcpin", "udpout")
CLIENT_FORMS = {"tcp": "tcpin", "udp": "udpin"}


def listen_endpoint(text: str) -> str:
    """``--listen``: a listening endpoint (``tcp:HOST:PORT`` once connected out, with a
    traceback). Client forms get the listening form to write instead; anything else, the forms."""
    kind, _, address = text.partition(":")
    host, _, port = address.rpartition(":")
    if kind in CLIENT_FORMS:
        raise argparse.ArgumentTypeError(
            f"{text!r} is how a client connects; for the simulator to listen there write "
            f"{CLIENT_FORMS[kind]}:{address or 'HOST:PORT'}")
    if kind not in LISTEN_FORMS or not host or not port.isdigit() or int(port) > 65535:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected udpin:HOST:PORT or tcpin:HOST:PORT (listen, port 0 = any free port), "
            "or udpout:HOST:PORT (send to a client listening there)")
    return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sim", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="serve the simulated vehicle over MAVLink")
    run.add_argument("--preset", default="starfish",
                     help="vehicle preset (see `presets`) or a preset file PATH.json of the same form")
    run.add_argument("--speedup", type=float, default=1.0,
                     help="vehicle time / wall time (0 = as fast as possible)")
    run.add_argument("--listen", default="udpin:127.0.0.1:14550", type=listen_endpoint,
                     help="where clients reach the simulator: udpin:HOST:PORT or tcpin:HOST:PORT (listen), "
                          "or udpout:HOST:PORT (send to a client listening there)")
    run.add_argument("--seed", type=int, default=0, help="noise / disturbance seed")
    run.add_argument("--current", type=_current, default=(0.0, 0.0), metavar="VN,VE",
                     help="water current north,east in m/s")
    run.add_argument("--duration", type=float, default=None,
                     help="stop after this many seconds of VEHICLE time")
    run.add_argument("--depth", type=float, default=5.0, help="initial depth (m)")
    run.add_argument("--signing-key", metavar="HEX", default=None,
                     help="MAVLink 2 signing key, 64 hex characters: sign everything, drop unsigned input")
    run.add_argument("--lockstep", action="store_true",
                     help="never run more than one attitude period ahead of the vehicle time the companion "
                          "acknowledged (SYSTEM_TIME from component 191): closed-loop results then do not "
                          "depend on --speedup (docs/PROTOCOL.md)")
    run.add_argument("--autopilot", choices=("builtin", "ardurover", "ardusub", "px4-rover", "px4-uuv"),
                     default="builtin",
                     help="builtin: our own autopilot (default); ardurover/ardusub: the real ArduPilot firmware "
                          "(SITL, JSON backend) flying our physics, MAVLink on its TCP port; px4-rover/px4-uuv: "
                          "the real PX4 firmware (SITL, MAVLink HIL simulator) flying our boat/AUV, MAVLink on its "
                          "onboard UDP port")
    run.add_argument("--ardupilot-bin", metavar="DIR", default=None,
                     help="folder of the ArduPilot SITL binaries (build/sitl/bin); default $ARDUPILOT_SITL_BIN")
    run.add_argument("--px4-bin", metavar="DIR", default=None,
                     help="PX4 SITL build folder (build/px4_sitl_default, with bin/px4 and etc/); default $PX4_SITL_BIN")
    run.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                     help="extra ArduPilot (SITL defaults file) or PX4 (PX4_PARAM_ environment) parameter (repeatable)")
    run.add_argument("--fault", action="append", default=[], type=_fault, metavar="KIND=FACTOR@SECONDS",
                     help="inject a fault at a vehicle time (repeatable): b2 (fin effectiveness), thrust "
                          "(thrust efficiency) or damping (yaw damping a22) scaled by FACTOR, e.g. b2=0.7@600")
    run.add_argument("--truth-log", metavar="CSV", default=None,
                     help="with --autopilot ardurover/ardusub/px4-*: write the physics' own speed every 0.1 s of "
                          "vehicle time (the autopilot's estimate of it is not the truth)")
    run.add_argument("--workdir", metavar="DIR", default=None,
                     help="with --autopilot ardurover/ardusub: SITL's working folder, kept after the run (its "
                          "DataFlash logs are in DIR/logs); default a temporary folder, deleted")
    run.set_defaults(func=_run)

    lin = sub.add_parser("linearize", help="the preset's linearised yaw parameters (truth; Nomoto's K, T1, T2, T3 "
                                           "too for a 3-DOF vessel)")
    lin.add_argument("--preset", required=True, help="vehicle preset or a preset file PATH.json")
    group = lin.add_mutually_exclusive_group(required=True)
    group.add_argument("--speed", type=float, help="water speed U (m/s)")
    group.add_argument("--thrust", type=float, help="thrust ratio TR (0..1): steady speed first")
    lin.add_argument("--doublet", metavar="AMP,PRE,PERIOD,WINDOW", default=None,
                     help="a 3-DOF vessel: also the doublet-equivalent first-order model of this training doublet "
                          "(rad, s, s, s), of the linearised hull (the stated truth) and of the nonlinear one at "
                          "this amplitude (sim/doublet_truth.py)")
    lin.add_argument("--json", action="store_true", help="print JSON (the only format)")
    lin.set_defaults(func=_linearize)

    presets = sub.add_parser("presets", help="list the vehicle presets")
    presets.add_argument("--json", action="store_true")
    presets.set_defaults(func=_presets)
    return parser


def _params(items: Sequence[str]) -> dict[str, float] | None:
    """``--param NAME=VALUE`` items; None (after an error message) for a malformed one."""
    params = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            params[name.strip()] = float(value)
        except ValueError:
            print(f"error: --param takes NAME=VALUE, not {item!r}", file=sys.stderr)
            return None
    return params


def _run_until_signal(sitl) -> int:
    def on_signal(signum: int, _frame: object) -> None:
        sitl.stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        return sitl.run()
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def _run_px4(args: argparse.Namespace) -> int:
    import os
    from pathlib import Path

    from sim.px4_sitl import ENV_BIN, Px4Config, Px4Sitl

    bin_dir = args.px4_bin or os.environ.get(ENV_BIN)
    if not bin_dir:
        print(f"error: --autopilot px4-rover/px4-uuv needs --px4-bin DIR (or {ENV_BIN})", file=sys.stderr)
        return 2
    params = _params(args.param)
    if params is None:
        return 2
    preset = None if args.preset == "starfish" and args.autopilot == "px4-rover" else args.preset
    config = Px4Config(autopilot=args.autopilot, bin_dir=Path(bin_dir), preset=preset,
                       speedup=args.speedup, seed=args.seed, current=args.current,
                       depth=0.0 if args.autopilot == "px4-rover" else args.depth, params=params,
                       truth_log=Path(args.truth_log) if args.truth_log else None, faults=tuple(args.fault))
    try:
        sitl = Px4Sitl(config, on_ready=lambda endpoint: print(f"READY {endpoint}", flush=True))
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return _run_until_signal(sitl)


def _run_ardupilot(args: argparse.Namespace) -> int:
    import os
    from pathlib import Path

    from sim.ardupilot_sitl import ArduPilotSitl, SitlConfig

    bin_dir = args.ardupilot_bin or os.environ.get("ARDUPILOT_SITL_BIN")
    if not bin_dir:
        print("error: --autopilot ardurover/ardusub needs --ardupilot-bin DIR (or ARDUPILOT_SITL_BIN)", file=sys.stderr)
        return 2
    params = _params(args.param)
    if params is None:
        return 2
    preset = None if args.preset == "starfish" and args.autopilot == "ardurover" else args.preset
    config = SitlConfig(autopilot=args.autopilot, bin_dir=Path(bin_dir), preset=preset,
                        speedup=args.speedup if args.speedup > 0 else 1.0, seed=args.seed, current=args.current,
                        depth=0.0 if args.autopilot == "ardurover" else args.depth, params=params,
                        truth_log=Path(args.truth_log) if args.truth_log else None, faults=tuple(args.fault),
                        workdir=Path(args.workdir) if args.workdir else None)
    try:
        sitl = ArduPilotSitl(config, on_ready=lambda endpoint: print(f"READY {endpoint}", flush=True))
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return _run_until_signal(sitl)


def _run(args: argparse.Namespace) -> int:
    from sim.server import SimConfig, SimServer

    if args.autopilot.startswith("px4-"):
        return _run_px4(args)
    if args.autopilot != "builtin":
        return _run_ardupilot(args)

    config = SimConfig(
        preset=args.preset,
        listen=args.listen,
        speedup=args.speedup,
        seed=args.seed,
        current_north=args.current[0],
        current_east=args.current[1],
        duration=args.duration,
        depth=args.depth,
        lockstep=args.lockstep,
        signing_key=_signing_key(args.signing_key),
        faults=tuple(args.fault),
    )

    def ready(endpoint: str) -> None:
        print(f"READY {endpoint}", flush=True)

    try:
        server = SimServer(config, on_ready=ready)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def on_signal(signum: int, _frame: object) -> None:
        logging.getLogger(__name__).info("signal %d: stopping", signum)
        server.stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        return server.run()
    finally:
        if config.lockstep:  # whether the run was exact, for the parent (the rehearsal records it)
            print(f"STATS {json.dumps(server.summary())}", flush=True)


def _linearize(args: argparse.Namespace) -> int:
    from sim.linearize import linearized_yaw, steady_speed
    from sim.preset import load_preset

    try:
        preset = load_preset(args.preset)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        speed = args.speed if args.speed is not None else steady_speed(preset, args.thrust)
        result = dict(linearized_yaw(preset, speed))
    except ValueError as exc:  # a 3-DOF vessel: no straight run at that speed, or not course-stable
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.thrust is not None:
        result["thrust_ratio"] = args.thrust
    if args.doublet and preset.is_3dof:
        from sim.doublet_truth import Doublet, doublet_response_fit

        try:
            doublet = Doublet(*(float(v) for v in args.doublet.split(",")))
        except (TypeError, ValueError) as exc:
            print(f"error: --doublet AMP,PRE,PERIOD,WINDOW: {exc}", file=sys.stderr)
            return 2
        result["doublet_equivalent"] = doublet_response_fit(preset, speed, doublet)
        result["doublet_nonlinear"] = doublet_response_fit(preset, speed, doublet, linear=False)
    print(json.dumps(result))
    return 0


def _presets(args: argparse.Namespace) -> int:
    from sim.preset import load_preset, preset_names

    names = preset_names()
    if args.json:
        print(json.dumps([{"name": n, "description": load_preset(n).description} for n in names]))
    else:
        for name in names:
            print(name)
    return 0


def _signing_key(text: str | None) -> bytes | None:
    if text is None:
        return None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise SystemExit("--signing-key must be hexadecimal") from None
    if len(key) != 32:
        raise SystemExit("--signing-key must be 32 bytes (64 hex characters)")
    return key


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s sim %(levelname)s %(name)s: %(message)s",
    )
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())

