"""The `graphkit` command line.

Exit codes: 0 success, 2 bad graph / bad input / bad usage / a problem of the environment
(a missing package, a NUL byte in a path, an unreadable or full disk, input nested too deeply),
1 a node failed, 130 interrupted (Ctrl-C), 141 the reader of the output went away (``| head``).
Nothing heavy is imported before :func:`main` runs, so a Ctrl-C at any moment is exit 130
without a traceback.
"""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from .errors import GraphkitError, UsageError, interrupt_in
from .memory import tune_malloc
from .nodeinfo import node_info, type_name

DEFAULT_CACHE = ".graphkit-cache"


def _cache_arg(p, from_graph: bool = False):
    """--cache and --cache-option; ``from_graph``: a command on a graph, whose file may name its
    cache (``cache:``; --cache replaces it, Graph.cache_setting)."""
    if from_graph:
        p.set_defaults(graph_cache=True)
        p.add_argument("--cache", default=None, help="cache folder or fsspec URL (default: the graph file's "
                       "cache:, else $GRAPHKIT_CACHE, else ./.graphkit-cache)")
    else:
        p.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", DEFAULT_CACHE),
                       help="cache folder or fsspec URL (default: $GRAPHKIT_CACHE or ./.graphkit-cache)")
    p.add_argument("--cache-option", action="append", default=[], metavar="KEY=VALUE",
                   help="an fsspec storage option for a cache URL (repeatable), e.g. endpoint_url=http://host:9000, "
                        "profile=NAME, client_kwargs.region_name=eu-west-1; also $GRAPHKIT_CACHE_OPTIONS (JSON)")


def _graph_args(p):
    p.add_argument("graph", help="graph file (YAML)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override a graph param (repeatable)")


def _version() -> str:
    import platform

    from . import __version__

    try:
        from importlib.metadata import version

        dist = f"relightkit {version('relightkit')}, "
    except Exception:  # noqa: BLE001 - not installed as a distribution
        dist = ""
    return f"graphkit {__version__} ({dist}Python {platform.python_version()})"


def _version_action(argparse):
    class VersionAction(argparse.Action):
        """--version, computed only when asked for (importing metadata costs start-up time)."""

        def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
            super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

        def __call__(self, parser, namespace, values, option_string=None):
            print(_version())
            parser.exit()

    return VersionAction


def _backend_arg(p):
    p.add_argument("--backend", default="", help="preferred backends, comma-separated (numpy is always last)")


def build_parser():
    import argparse

    ap = argparse.ArgumentParser(prog="graphkit", description="Run typed node graphs with a content-hash cache.")
    ap.add_argument("--version", action=_version_action(argparse), help="print the version and exit")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    for add in (_run_parser, _inspect_parsers, _tool_parsers, _serve_parser, _cache_parser):
        add(sub)  # in this order: `graphkit --help` lists the commands as they are added
    return ap


def _run_parser(sub) -> None:
    p = sub.add_parser("run", help="run a graph")
    _graph_args(p)
    _cache_arg(p, from_graph=True)
    p.add_argument("--out", default="out", help="folder for the outputs, manifest.json and report.html (default: out)")
    _backend_arg(p)
    p.add_argument("--jobs", "-j", type=int, default=os.cpu_count() or 1, help="nodes run at once")
    p.add_argument("--executor", choices=("local", "dask"), default="local")
    p.add_argument("--scheduler", default=None,
                   help="Dask scheduler address, e.g. tcp://host:8786 (default: a local cluster)")
    p.add_argument("--scheduler-timeout", type=float, default=10.0, metavar="SECONDS",
                   help="give up (exit 2) when the Dask scheduler does not answer within this time (default 10)")
    p.add_argument("--output", action="append", default=[], metavar="NAME",
                   help="only compute these outputs (repeatable; a swept output's name selects all its instances)")
    p.add_argument("-n", "--dry-run", action="store_true",
                   help="run nothing: print per node instance 'cached' or 'would run' and why")
    p.add_argument("-q", "--quiet", action="store_true", help="print only notices and errors")
    p.add_argument("-v", "--verbose", action="store_true", help="also list the nodes found in the cache")


def _inspect_parsers(sub) -> None:
    """status, validate, show (explain comes after conform)."""
    p = sub.add_parser("status", help="per node instance: cached or would run, and why (runs nothing)")
    _graph_args(p)
    _cache_arg(p, from_graph=True)
    _backend_arg(p)
    p.add_argument("--output", action="append", default=[], metavar="NAME", help="only these outputs (repeatable)")
    p.add_argument("--json", action="store_true", help="print JSON (for tools)")

    p = sub.add_parser("validate", help="check a graph without running it")
    _graph_args(p)

    p = sub.add_parser("show", help="print the graph as mermaid or DOT")
    _graph_args(p)
    p.add_argument("--format", choices=("mermaid", "dot"), default="mermaid")
    p.add_argument("--status", action="store_true", help="colour nodes by what a run would do (cached / would run)")
    p.add_argument("--instances", action="store_true", help="draw every instance of a swept node")
    _cache_arg(p)
    _backend_arg(p)


def _tool_parsers(sub) -> None:
    """conform, explain, nodes, schema."""
    p = sub.add_parser("conform", help="check backends against the numpy reference on the nodes' examples, "
                       "and that every declared port constraint refuses a value that breaks it")
    p.add_argument("plugin", nargs="?", help="only the backends this plugin (distribution or GRAPHKIT_PLUGINS module) provides")
    p.add_argument("--node", action="append", default=[], metavar="TYPE", help="only these node types (repeatable)")
    p.add_argument("--allow-unavailable", action="store_true",
                   help="exit 0 even when a backend cannot run here (it is still listed)")

    p = sub.add_parser("explain", help="say why a node would (not) re-run")
    _graph_args(p)
    p.add_argument("node")
    _cache_arg(p, from_graph=True)

    p = sub.add_parser("nodes", help="list node types (or describe one)")
    p.add_argument("name", nargs="?")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("schema", help="print the JSON Schema of graph files")
    p.add_argument("-o", "--output", default=None)


def _serve_parser(sub) -> None:
    p = sub.add_parser("serve", help="open the graph in a local web studio")
    p.add_argument("graph", help="graph file (YAML)")
    _cache_arg(p)
    p.add_argument("--out", default="out", help="folder for the outputs and manifest.json of each run (default: out)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: 127.0.0.1, this machine only)")
    p.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    p.add_argument("--backend", default="", help="preferred backends, comma-separated (numpy is always last)")
    p.add_argument("--jobs", "-j", type=int, default=1, help="nodes run at once (default: 1)")
    p.add_argument("--no-run", action="store_true", help="do not run on open or on each change (press Run)")
    p.add_argument("--open", action="store_true", help="open the URL in a web browser")


def _cache_parser(sub) -> None:
    p = sub.add_parser("cache", help="inspect or trim the cache")
    csub = p.add_subparsers(dest="cache_cmd", required=True, metavar="ACTION")
    for name, hlp in (("ls", "list entries"), ("gc", "trim to a size"), ("verify", "re-hash everything"),
                      ("info", "where the cache is and how it is reached (endpoint, region, credentials' source)"),
                      ("init", "create the cache's bucket or folder (never created implicitly on object stores)")):
        cp = csub.add_parser(name, help=hlp)
        if name == "init":
            cp.add_argument("url", nargs="?", help="the cache's folder or URL (default: --cache)")
        if name == "info":
            cp.add_argument("graph", nargs="?", help="a graph file: the cache its runs use (its cache:, or --cache)")
        _cache_arg(cp, from_graph=name == "info")
        if name == "gc":
            cp.add_argument("--max-size", required=True, help="e.g. 500M (MiB), 2G (GiB): binary units")
        if name == "verify":
            cp.add_argument("--repair", action="store_true", help="remove what is corrupt")


_INTERRUPTED = []  # a SIGINT arrived (see _on_sigint)


def _on_sigint(signum, frame):
    """Python's own SIGINT behaviour (KeyboardInterrupt), remembered: a Ctrl-C that lands inside a
    C extension's import (numpy's) comes back as an ImportError, and must still read as Ctrl-C."""
    import _signal  # the C module: `signal` itself imports enum, too slow to do under a Ctrl-C

    _INTERRUPTED.append(signum)
    _signal.default_int_handler(signum, frame)


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see the module docstring)."""
    try:
        import _signal

        if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
            _signal.signal(_signal.SIGINT, _on_sigint)
        tune_malloc()
        code = _main(argv)
        sys.stdout.flush()  # a reader that went away shows here, not at interpreter exit
        return code
    except KeyboardInterrupt:
        _print_err("graphkit: interrupted")
        return 130
    except BrokenPipeError:  # `graphkit nodes --json | head`: stop quietly, as Unix tools do
        _silence_stdout()
        return 141


def _main(argv) -> int:
    args = build_parser().parse_args(argv)
    try:
        _check_no_nul(args)
        _set_cache_options(getattr(args, "cache_option", None))
        return _dispatch(args)
    except GraphkitError as e:
        from .errors import GraphError

        if _interrupted(e):  # e.g. a node's module whose import a Ctrl-C broke: "cannot import …"
            raise KeyboardInterrupt from None
        print(str(e) if isinstance(e, GraphError) else f"graphkit: {e}", file=sys.stderr)
        return e.exit_code
    except (KeyboardInterrupt, BrokenPipeError):
        raise
    except Exception as e:  # noqa: BLE001 - told apart in _report: one line, not a traceback
        if _interrupted(e):
            raise KeyboardInterrupt from None
        return _report(e)


def _interrupted(e: BaseException) -> bool:
    """Whether an error is a Ctrl-C in disguise: the interrupt in its chain
    (:func:`~graphkit.errors.interrupt_in`), or any error after the handler saw a SIGINT (a C
    extension's import turns it into an ImportError: numpy's)."""
    return interrupt_in(e) or bool(_INTERRUPTED)


def _report(e: Exception) -> int:
    """One line on stderr for what reached the top, and its exit code."""
    if isinstance(e, RecursionError):
        print("graphkit: input nested too deeply (over Python's recursion limit)", file=sys.stderr)
        return 2
    if isinstance(e, ImportError):  # the environment lacks a package (e.g. s3fs for --cache s3://)
        print(f"graphkit: a required Python package is missing: {_import_message(e)}", file=sys.stderr)
        return 2
    if isinstance(e, MemoryError):
        print("graphkit: out of memory", file=sys.stderr)
        return 2
    if isinstance(e, OSError):  # the disk or the OS refused (full, read-only, permissions)
        where = f"{e.filename}: " if e.filename else ""
        print(f"graphkit: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    # a bug in graphkit itself: one line, not a traceback
    if os.environ.get("GRAPHKIT_TRACEBACK"):
        raise e
    print(f"graphkit: internal error: {type(e).__name__}: {e} (set GRAPHKIT_TRACEBACK=1 for details)",
          file=sys.stderr)
    return 1


def _check_no_nul(args) -> None:
    """A NUL byte cannot be part of a path (the OS would raise ValueError deep inside)."""
    for name, value in vars(args).items():
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str) and "\0" in v:
                opt = name if name in ("graph", "name", "node") else "--" + name.replace("_", "-")
                raise UsageError(f"{opt}: {v!r} holds a NUL byte")


def _import_message(e: ImportError) -> str:
    name = e.name or getattr(e.__cause__, "name", None)
    text = str(e)
    return text if not name or name in text else f"{text} (package '{name}')"


def _print_err(msg: str) -> None:
    try:
        print(msg, file=sys.stderr)
    except (OSError, ValueError):
        pass


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def _registry():
    from .registry import default_registry

    reg = default_registry()
    for msg in reg.problems:
        print(f"warning: {msg}", file=sys.stderr)
    return reg


def _load(args, check_backends=True):
    from .graphfile import load_graph, parse_set

    return load_graph(args.graph, _registry(), parse_set(args.set), check_backends=check_backends)


def _dispatch(args) -> int:
    cmd = _COMMANDS.get(args.cmd)
    if cmd is None:
        raise UsageError(f"unknown command {args.cmd}")
    return cmd(args)


def cmd_validate(args) -> int:
    g = _load(args)
    grouped = {o for v in g.output_groups.values() for o in v}
    outs = [f"{k} (×{len(v)})" for k, v in g.output_groups.items()] + [o for o in g.outputs if o not in grouped]
    sweeps = "".join(f", sweep {n} ×{len(s)}" for n, s in g.sweeps.items())
    print(f"{args.graph}: ok ({len(g.nodes)} nodes{sweeps}; outputs: {', '.join(outs)})")
    return 0


def cmd_explain(args) -> int:
    from .explain import explain
    from .store import Store

    graph = _load(args)
    loc, options, _ = graph.cache_setting(args.cache)
    print(explain(graph, Store(loc, options=options).open(), args.node))
    return 0


def cmd_schema(args) -> int:
    import json

    from .schema import graph_schema

    text = json.dumps(graph_schema(_registry()), indent=1)
    if args.output:
        Path(args.output).write_text(text + "\n")
    else:
        print(text)
    return 0


def cmd_serve(args) -> int:
    from .studio import serve

    if args.jobs < 1:
        raise UsageError("--jobs must be at least 1")
    return serve(args.graph, host=args.host, port=args.port, cache=args.cache, out=args.out,
                 backends=[b.strip() for b in args.backend.split(",") if b.strip()],
                 jobs=args.jobs, autorun=not args.no_run, registry=_registry(), open_browser=args.open)


def _set_cache_options(given: list[str] | None) -> None:
    """`--cache-option KEY=VALUE`s over $GRAPHKIT_CACHE_OPTIONS, for every store this process
    (and the Dask workers it starts) opens."""
    if given:
        import json

        from .store import OPTIONS_ENV, cache_options, merged_options, parse_cache_option

        os.environ[OPTIONS_ENV] = json.dumps(merged_options(cache_options(), dict(map(parse_cache_option, given))))


def _store(location):
    from .store import Store

    return Store(location).open()


def _backends(args) -> list[str]:
    return [b.strip() for b in args.backend.split(",") if b.strip()]


def _status_report(args):
    from .graphfile import parse_set
    from .dryrun import status

    reg = _registry()
    return status(args.graph, args.cache, registry=reg, backends=_backends(args),
                  overrides=parse_set(args.set), outputs=getattr(args, "output", None) or None)


def cmd_status(args) -> int:
    import json

    report = _status_report(args)
    if getattr(args, "json", False):
        print(json.dumps(report.to_json(), indent=1))
        return 0
    for line in report.lines():
        print(line)
    print(report.summary() + (" (dry run: nothing was run)" if args.cmd == "run" else ""))
    return 0


def cmd_run(args) -> int:
    import gc

    from .api import run_graph
    from .graphfile import load_graph, parse_set
    from .progress import make_progress

    if args.jobs < 1:
        raise UsageError("--jobs must be at least 1")
    if args.dry_run:
        return cmd_status(args)
    progress = make_progress(args.quiet, args.verbose)
    reg = _registry()
    graph = load_graph(args.graph, reg, parse_set(args.set))
    gc.freeze()  # what is loaded lives until this process ends: the collector need not traverse it again
    run = run_graph(graph, cache=args.cache, out=args.out,
                    backends=_backends(args),
                    jobs=args.jobs, outputs=args.output or None, executor=args.executor,
                    scheduler=args.scheduler, registry=reg, progress=progress,
                    scheduler_timeout=args.scheduler_timeout)
    if not args.quiet:
        print(f"{run.graph.name}: {len(run.computed)} computed, {len(run.cached)} cached, "
              f"{run.result.seconds:.2f}s; {len(run.files)} files in {args.out}/", file=sys.stderr)
    return 0


def cmd_show(args) -> int:
    from .show import draw

    if args.status:
        report = _status_report(args)
        print(draw(report.graph, args.format, report, args.instances))
    else:
        print(draw(_load(args, check_backends=False), args.format, None, args.instances))
    return 0


def cmd_conform(args) -> int:
    from .conformance import conform

    findings = conform(_registry(), plugin=args.plugin, nodes=args.node or None)
    bad = [f for f in findings if not f.ok and f.checked]
    unchecked = [f for f in findings if not f.checked]
    for f in findings:
        print(_finding_line(f))
    print(f"{len(findings) - len(bad) - len(unchecked)} ok, {len(bad)} failed, {len(unchecked)} not checked"
          + (f" ({', '.join(sorted({f'{f.node}/{f.backend}' for f in unchecked}))})" if unchecked else ""))
    if bad:
        return 1
    return 2 if unchecked and not args.allow_unavailable else 0


def _finding_line(f) -> str:
    from .conformance import CONTRACT

    state = "ok" if f.ok else ("FAIL" if f.checked else "skip")
    case = f" example {f.case}" if f.case >= 0 else ""
    return f"{state:<4}  {f.node}/{f.backend}{case}" + ("" if f.ok and f.backend != CONTRACT else f": {f.message}")


def cmd_nodes(args) -> int:
    import json

    reg = _registry()
    if args.name and args.name not in reg.nodes:
        from .graphfile import did_you_mean

        raise UsageError(f"unknown node type '{args.name}'{did_you_mean(args.name, reg.nodes)}")
    rows = []
    for n in [args.name] if args.name else reg.node_names():
        try:
            rows.append(node_info(reg, n))
        except GraphkitError as e:
            print(f"warning: {e}", file=sys.stderr)
    if args.json:
        print(json.dumps(rows, indent=1))
    elif args.name:
        for r in rows:
            _print_node(r)
    else:
        for r in rows:
            print(f"{r['type']:<24} {r['doc'].splitlines()[0] if r['doc'] else ''}")
    return 0


def _print_node(r: dict) -> None:
    import json

    from .contract import Constraints

    print(f"{r['type']} (version {r['version']}, from {r['provider']}; backends: {', '.join(r['backends'])})\n")
    print(r["doc"] + "\n")
    for key in ("inputs", "outputs"):
        print(f"{key}:")
        for pn, p in r[key].items():
            opt = " (optional)" if p.get("optional") else ""
            needs = Constraints.from_json(p.get("constraints", {})).describe()
            print(f"  {pn}: {p['type']}{opt}  {p['doc']}" + (f"  [needs: {'; '.join(needs)}]" if needs else ""))
    print("params:")
    for pn, p in r["params"].items():
        default = "(required)" if p["required"] else f"= {json.dumps(p['default'], ensure_ascii=False)}"
        print(f"  {pn}: {p['type']} {default}  {p['doc']}".rstrip())
    if r["hooks"]:
        print(f"hooks (a backend may replace): {', '.join(r['hooks'])}")
    if r["studio_view"]:
        print(f"studio view: {r['studio_view']}")


def _parse_size(s: str) -> int:
    """A size in bytes; suffixes are binary (K = KiB = 2^10, M = MiB = 2^20, G, T), as shown by
    `cache ls` and gc.  Decimal-looking suffixes (MB, GB) are refused rather than guessed."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*(?:([kKmMgGtT])(i?)([bB]?))?\s*", s)
    if not m or (m.group(4) and not m.group(3)):
        hint = ""
        if m:
            hint = f"; sizes are binary: write {m.group(1)}{m.group(2).upper()} or {m.group(1)}{m.group(2).upper()}iB"
        raise UsageError(f"--max-size: cannot read {s!r}{hint} (examples: 500M = 500 MiB, 2G = 2 GiB, 100000 bytes)")
    unit = (m.group(2) or "").lower()
    mult = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}[unit]
    return int(float(m.group(1)) * mult)


def cmd_cache(args) -> int:
    if args.cache_cmd == "init":
        from .store import Store

        print(Store(args.url or args.cache).init())
        return 0
    if args.cache_cmd == "info":
        return _cache_info(args)
    actions = {"ls": _cache_ls, "gc": _cache_gc}
    return actions.get(args.cache_cmd, _cache_verify)(_store(args.cache), args)


def _cache_setting(args) -> tuple[str, dict, str]:
    """(location, storage options, where from) of a graph command's cache (Graph.cache_setting)."""
    if getattr(args, "graph", None):
        from .graphfile import load_graph

        return load_graph(args.graph, _registry(), {}, check_backends=False).cache_setting(args.cache)
    if args.cache is not None:
        return args.cache, {}, "--cache"
    env = os.environ.get("GRAPHKIT_CACHE")
    return (env, {}, "$GRAPHKIT_CACHE") if env else (DEFAULT_CACHE, {}, "the default")


def _cache_info(args) -> int:
    from .store import Store

    loc, options, source = _cache_setting(args)
    print(f"setting: {source}")
    for k, v in Store(loc, options=options).open().fs.info().items():
        print(f"{k}: {v}")
    return 0


def _cache_ls(store, args) -> int:
    from .store import fmt_size

    rows = store.ls()
    for r in rows:
        flag = "  CORRUPT" if r.get("corrupt") else ""
        print(f"{r['key'][:16]}  {r['type']:<20} {r['node']:<20} {fmt_size(r['bytes']):>14}{flag}")
    u = store.usage()
    print(f"{len(rows)} entries, {fmt_size(u['total'])} in {store.location} (objects {fmt_size(u['objects'])}, "
          f"each counted once; records {fmt_size(u['keys'] + u['journal'])}; tmp {fmt_size(u['tmp'])}; "
          f"quarantine {fmt_size(u['quarantine'])}; other {fmt_size(u['runs'] + u['locks'] + u['other'])}; "
          "MiB = 2^20 bytes)")
    return 0


def _cache_gc(store, args) -> int:
    from .store import fmt_size

    info = store.gc(_parse_size(args.max_size))
    print(f"removed {info['removed_records']} records, {info['removed_objects']} objects and "
          f"{info['stale_files']} stale temp, lock, quarantined and unlinked journal files "
          f"({fmt_size(info['stale_bytes'])}); "
          f"{fmt_size(info['bytes'])} left in {store.location}")
    return 0


def _cache_verify(store, args) -> int:
    from .store import fmt_size

    stale = store.clean_stale(dry_run=True)
    problems = store.verify(repair=args.repair)
    for p in problems:
        print(p)
    if stale["files"]:
        print(f"{stale['files']} stale temp, lock, quarantined and unlinked journal files "
              f"({fmt_size(stale['bytes'])})"
              + (" removed" if args.repair else "; `verify --repair` or `gc` removes them"))
    print(f"{len(problems)} problems" + (" (repaired)" if args.repair and problems else "") + f" in {store.location}")
    return 0 if not problems or args.repair else 1


_COMMANDS = {"run": cmd_run, "validate": cmd_validate, "show": cmd_show, "status": cmd_status,
             "conform": cmd_conform, "explain": cmd_explain, "nodes": cmd_nodes, "schema": cmd_schema,
             "cache": cmd_cache, "serve": cmd_serve}


def show(graph, fmt: str) -> str:
    """The graph as mermaid or DOT (kept for callers of the old function; see graphkit.show)."""
    from .show import draw

    return draw(graph, fmt)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
