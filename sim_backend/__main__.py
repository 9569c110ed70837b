"""``python -m sim_backend``: the simulated hardware as its own process (``cheope sim`` does the same)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from controller.config import CONFIG_DIR, ConfigError, load_config, parse_override
from drivers.bus import BusSpecError, parse_bus_spec
from sim_backend.process import serve


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backend", description=__doc__)
    ap.add_argument("--config", help="TOML configuration (default: the shipped cheope.toml)")
    ap.add_argument("--robot", choices=("cheope", "uru", "nspu"),
                    help="loads controller/configs/ROBOT.toml unless --config is given (then sets robot.kind)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    ap.add_argument("--can", help="INTERFACE[:CHANNEL], default from the config's bus.can")
    ap.add_argument("--udp-port", type=int, help="UDP port of the udp_multicast bus")
    ap.add_argument("--fd", action="store_true", help="CAN FD frames")
    args = ap.parse_args(argv)
    try:
        sets = ([f'robot.kind="{args.robot}"'] if args.robot else []) + list(args.set)
        path = args.config or (str(CONFIG_DIR / f"{args.robot}.toml") if args.robot else None)
        cfg = load_config(path, dict(parse_override(s) for s in sets))
        spec = parse_bus_spec(args.can or cfg.bus.can, fd=args.fd or cfg.bus.fd,
                              udp_port=args.udp_port or cfg.bus.udp_port)
    except (ConfigError, BusSpecError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    serve(cfg, spec, stop, lambda line: print(line, flush=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
