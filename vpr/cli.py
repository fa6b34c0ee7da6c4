"""The ``vpr`` command line.

Each sub-command lives in the module that implements it, which provides a
function adding its arguments (``add_arguments(parser, command)`` unless named
otherwise below) and one running it (``run_command(args) -> int``; ``args.command``
names the command); modules are imported
only when their command runs, so ``vpr --help`` stays fast.

Bad input (missing or corrupt files, wrong arguments) ends the run with one line
on stderr and exit status 2; an unexpected failure exits with status 1.
"""
from __future__ import annotations

import argparse
import importlib
import sys

#: command -> (module, one-line help); modules named in _FUNCS use other function names
COMMANDS = {
    "demo": ("pipelines.demo", "render the two_seasons scene and compare rSHOSM, SeqSLAM and pairwise on it"),
    "match": ("pipelines.match", "match a query traverse against a database traverse (folders, videos, lists)"),
    "compare": ("pipelines.match", "run several methods on the same database/query and tabulate their metrics"),
    "loops": ("pipelines.match", "loop closures within one traverse (the paper's setting)"),
    "render": ("vpr.render", "render a procedural scene specification to image folders and ground truth"),
    "paper-fig3": ("pipelines.paper_fig3", "reproduce Fig. 3 of the paper on the simulated grid world"),
    "nordland": ("pipelines.nordland", "Nordland summer vs winter benchmark (needs the dataset)"),
}


_FUNCS = {"vpr.render": ("add_render_arguments", "run_render_command")}


def _module(cmd):
    return importlib.import_module(COMMANDS[cmd][0])


def _funcs(cmd):
    mod = _module(cmd)
    add, run = _FUNCS.get(COMMANDS[cmd][0], ("add_arguments", "run_command"))
    adder = getattr(mod, add)
    return (adder if add == "add_arguments" else (lambda p, _cmd: adder(p))), getattr(mod, run)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    from vpr import __version__

    ap = argparse.ArgumentParser(prog="vpr", description="Sequence-based visual place recognition: "
                                 "rSHOSM, SeqSLAM and pairwise matching, evaluation and plots.")
    ap.add_argument("--version", action="version", version=f"vpr {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for cmd, (_, help_) in COMMANDS.items():
        p = sub.add_parser(cmd, help=help_, description=help_)
        if only is None or cmd == only:
            try:
                adder, _ = _funcs(cmd)
            except ModuleNotFoundError as e:
                if only == cmd:
                    raise
                p.description = f"{help_} (unavailable: {e})"
                continue
            adder(p, cmd)
    return ap


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # build only the chosen command's arguments (cheap imports for --help and typos)
    cmd = next((a for a in argv if not a.startswith("-")), None)
    only = cmd if cmd in COMMANDS else None
    try:
        ap = build_parser(only if only else "__none__")
    except ModuleNotFoundError as e:
        print(f"vpr: error: command {cmd!r} is unavailable ({e})", file=sys.stderr)
        return 2
    args = ap.parse_args(argv)
    if not args.command:
        ap.print_help()
        return 2
    from vpr.memory import MemoryFileError

    try:
        return int(_funcs(args.command)[1](args) or 0)
    except KeyboardInterrupt:
        print("vpr: interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError,
            MemoryFileError) as e:
        msg = " ".join(str(e).split())
        print(f"vpr {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
