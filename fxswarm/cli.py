"""The ``fxswarm`` command: one subcommand per module, loaded on demand.

Each subcommand module exposes ``add_arguments(parser)`` and
``main(args) -> int``; this file only names them, so that adding a command
touches one line here and ``fxswarm sim`` never imports Zenoh or Rerun.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import signal
import sys

COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("fxswarm.launch.sim_cli", "run a scenario in one process (lock-step, in-memory bus)"),
    "expand": ("fxswarm.launch.expand", "print a scenario's explicit form (its [swarm] table written out as robots and graph)"),
    "run": ("fxswarm.launch.launcher", "run a scenario as one OS process per role over Zenoh"),
    "world": ("fxswarm.world.process", "the world process"),
    "leader": ("fxswarm.leader.process", "the virtual leader process"),
    "agent": ("fxswarm.agents.process", "one robot's process"),
    "logger": ("fxswarm.logger.process", "the Rerun logger process"),
    "router": ("fxswarm.runtime.router", "a Zenoh router (a Python session in router mode)"),
    "keys": ("fxswarm.security.keys", "a private CA and a certificate + key per process of a scenario (secure mode)"),
    "report": ("fxswarm.report", "PNG figures and index.md from a run folder"),
    "sweep": ("fxswarm.study.sweep", "settling time against initial error, per controller variant"),
    "check": ("fxswarm.study.check", "whether a scenario's graph meets W-MSR's condition for F liars"),
    "campaign": ("fxswarm.study.campaign", "many in-process runs over a grid of faults and laws, with statistics"),
    "compose": ("fxswarm.launch.compose", "write a docker-compose file for a scenario"),
    "stack": ("fxswarm.launch.stack", "write a Docker Swarm stack (stack.yml) for a scenario"),
    "k8s": ("fxswarm.launch.k8s", "write Kubernetes manifests (kubectl apply -f DIR) for a scenario"),
    "attach": ("fxswarm.launch.attach", "observe a running swarm through its router; write its run folder here"),
    "health": ("fxswarm.runtime.health", "exit 0 if a process of the swarm is alive (its liveliness token)"),
}


def _available() -> dict[str, tuple[str, str]]:
    """The commands whose module is installed (the rest are listed once they land)."""
    out = {}
    for name, spec in COMMANDS.items():
        try:
            found = importlib.util.find_spec(spec[0]) is not None
        except ModuleNotFoundError:
            found = False
        if found:
            out[name] = spec
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fxswarm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, (module_name, help_text) in _available().items():
        sub_parser = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:  # import only the command that runs: `sim` never loads Zenoh or Rerun
            importlib.import_module(module_name).add_arguments(sub_parser)
    args = parser.parse_args(argv)
    # Started as `cmd &` by a script, a command inherits SIGINT ignored, so Python installs no
    # KeyboardInterrupt and `kill -INT` does nothing (attach, campaign); Ctrl-C at a terminal
    # never reaches a background job anyway, so hearing it costs nothing there.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    module = importlib.import_module(COMMANDS[args.command][0])
    try:
        return int(module.main(args) or 0)
    except KeyboardInterrupt:
        return 130
    except OSError as exc:  # a file or folder the command could not read or write: one line, no traceback
        print(f"fxswarm {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
