"""What every ``stiction bench`` sweep shares: cases, a resumable CSV, stamps, a progress bar, and
where the cases run (local worker processes, or a Dask cluster with ``--cluster``).

A bench is one module of :mod:`stiction.bench` with this contract::

    NAME = "work-precision"            # stiction bench NAME
    HELP = "one line"
    FIELDS = (...)                     # the CSV columns in order: the documented row schema
    KEY_FIELDS = (...)                 # the fields that identify a case (resume skips those present)
    DEFAULT_WORKERS = None             # None: one worker per core; 1 when timings must have the machine
    def add_arguments(parser): ...     # its own options
    def cases(args) -> list[dict]      # JSON-able parameters, every KEY_FIELD among them; seeded
    def evaluate(case) -> dict         # module level (pickled to a worker): one row with every FIELD;
                                       # a failing method is data (failed / failure), never an exception
    def summarize(rows) -> dict        # extra top-level keys of the JSON
    def plot(rows, out_dir, stamp) -> list[Path]
    def result_stem(args) -> str       # optional: OUT/<stem>.json when one CSV holds several runs

Rows do not depend on where a case ran: a case is evaluated by the same function, from the same
parameters (seeds included), in a local process or on a Dask worker. Rows are appended to
``OUT/NAME.csv`` as they arrive, so an interrupted sweep resumes where it stopped; ``OUT/NAME.json``
holds the stamp and the summary (the rows are the CSV's).
"""
from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import os
import platform
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterable, Iterator

from .._optional import require
from .._validation import positive_int

COMMON_OPTIONS = ("json", "out", "quick", "cluster", "workers")


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help='print {"command", "stamp", "rows", ...} as JSON')
    parser.add_argument("--out", metavar="DIR", help="write DIR/NAME.csv (resumable: cases already there are "
                        "skipped), DIR/NAME.json and the PNG charts")
    parser.add_argument("--quick", action="store_true", help="a small version (two points per sweep)")
    parser.add_argument("--cluster", metavar="ADDRESS", help="run the cases on a Dask distributed cluster: its "
                        "scheduler address, or 'local' for a LocalCluster on this machine (extra: cluster)")
    parser.add_argument("--workers", type=positive_int, metavar="N",
                        help="local worker processes (default: the bench's; one per core for most)")


# ---- stamps ---------------------------------------------------------------------------------------

def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(module)
    except PackageNotFoundError:
        return None


def git_revision() -> str | None:
    """The commit of a source checkout (None for an installed wheel)."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True, timeout=5).stdout.strip()
    return out.stdout.strip() + ("+dirty" if dirty else "")


def git_description() -> str:
    """The commit in words, for the benchmark scripts' reports."""
    rev = git_revision()
    return "git revision unknown" if rev is None else "git " + rev.replace("+dirty", " + local changes")


def machine_description() -> str:
    return f"{platform.machine()} ({cpu_model()}, {os.cpu_count()} cores)"


def stamp(command: str) -> dict:
    """Machine, cores, date, versions and the command: printed with every result, drawn on every figure."""
    versions = {name: _version(dist) for name, dist in
                (("stiction", "stiction"), ("pinocchio", "pin"), ("numpy", "numpy"), ("mujoco", "mujoco"))}
    versions["python"] = platform.python_version()
    return {"command": command, "machine": f"{cpu_model()} ({platform.system()} {platform.machine()})",
            "cores": os.cpu_count(), "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "versions": {k: v for k, v in versions.items() if v is not None}, "git": git_revision()}


def stamp_text(st: dict) -> str:
    versions = " ".join(f"{k} {v}" for k, v in st["versions"].items())
    git = f" @{st['git']}" if st.get("git") else ""
    return f"{st['command']}  |  {st['date']}  |  {st['machine']}, {st['cores']} cores  |  {versions}{git}"


def stamp_figure(fig, st: dict) -> None:
    """The stamp along the bottom edge of a matplotlib figure (call before saving)."""
    fig.text(0.005, 0.003, stamp_text(st), fontsize=5.5, color="0.35", ha="left", va="bottom")


# ---- CSV: the raw data next to every figure, and what makes a sweep resumable ---------------------

def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "True" if value else "False"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (int, str)):
        return str(value)
    try:  # numpy scalars
        import numpy as np

        if isinstance(value, np.bool_):
            return "True" if value else "False"
        if isinstance(value, np.integer):
            return str(int(value))
        if isinstance(value, np.floating):
            return repr(float(value))
    except ImportError:
        pass
    raise TypeError(f"a row value must be a number, a string, a bool or None, got {type(value).__name__}: {value!r}")


def _parse(text: str) -> Any:
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    if text.lstrip("-").isdigit():
        return int(text)
    try:
        return float(text)
    except ValueError:
        return text


def case_key(case: dict, key_fields: Iterable[str]) -> tuple[str, ...]:
    """A case's identity as CSV text, so a case and its row read back from the CSV compare equal."""
    return tuple(_cell(case[k]) for k in key_fields)


def drop_partial_last_line(path: Path) -> bool:
    """Cut a CSV back to its last complete line when a run was interrupted mid-write (the file does
    not end in a newline): the next row must start on a line of its own, never be glued onto the
    fragment, and the fragment's case runs again. True when something was dropped."""
    with open(path, "rb+") as fh:
        size = fh.seek(0, os.SEEK_END)
        if size == 0:
            return False
        fh.seek(size - 1)
        if fh.read(1) == b"\n":
            return False
        # the last newline before the end (rows are short: read back in blocks until one is found)
        end, keep = size, 0
        while end > 0:
            start = max(0, end - 65536)
            fh.seek(start)
            block = fh.read(end - start)
            at = block.rfind(b"\n")
            if at >= 0:
                keep = start + at + 1
                break
            end = start
        fh.truncate(keep)
    return True


def read_csv(path: Path, fields: tuple[str, ...]) -> list[dict]:
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            return []
        if tuple(header) != tuple(fields):
            raise ValueError(f"{path}: its columns {header} are not this bench's ({', '.join(fields)}): "
                             "write to another --out folder or remove the file")
        rows = []
        for line in reader:
            if len(line) != len(fields):  # a line cut short by an interrupted run: run that case again
                continue
            rows.append({k: _parse(v) for k, v in zip(fields, line)})
        return rows


class _CsvAppender:
    def __init__(self, path: Path, fields: tuple[str, ...]):
        new = not path.exists() or path.stat().st_size == 0
        self._fh = open(path, "a", newline="")
        self._writer = csv.writer(self._fh)
        self._fields = fields
        if new:
            self._writer.writerow(fields)
            self._fh.flush()

    def write(self, row: dict) -> None:
        self._writer.writerow([_cell(row[k]) for k in self._fields])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


# ---- evaluation ------------------------------------------------------------------------------------

def _check_row(module: ModuleType, case: dict, row: Any) -> dict:
    if not isinstance(row, dict):
        raise RuntimeError(f"{module.NAME}: evaluate returned a {type(row).__name__}, not a row dict")
    missing = [k for k in module.FIELDS if k not in row]
    extra = [k for k in row if k not in module.FIELDS]
    if missing or extra:
        raise RuntimeError(f"{module.NAME}: a row does not match FIELDS (missing {missing}, unknown {extra})")
    if case_key(row, module.KEY_FIELDS) != case_key(case, module.KEY_FIELDS):
        raise RuntimeError(f"{module.NAME}: the row's key fields differ from its case's ({case})")
    for k in module.FIELDS:
        _cell(row[k])  # a value the CSV can hold
    return {k: row[k] for k in module.FIELDS}


def _progress(total: int, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="case", file=sys.stderr, disable=None, leave=False)


def evaluate_cases(evaluate: Callable[[dict], dict], cases: list[dict], workers: int = 1,
                   cluster: str | None = None) -> Iterator[tuple[dict, dict]]:
    """(case, row) pairs as they finish: in this process (workers = 1), on `workers` local processes,
    or on a Dask cluster (`cluster`: a scheduler address, or "local" for a LocalCluster of `workers`
    single-threaded processes)."""
    if not cases:
        return
    if cluster:
        yield from _evaluate_dask(evaluate, cases, workers, cluster)
    elif workers <= 1 or len(cases) == 1:
        for case in cases:
            yield case, evaluate(case)
    else:
        # forkserver: the workers start clean (no C++ thread pools or open files inherited)
        with ProcessPoolExecutor(max_workers=min(workers, len(cases)), mp_context=get_context("forkserver")) as pool:
            futures = {pool.submit(evaluate, case): case for case in cases}
            for fut in as_completed(futures):
                yield futures[fut], fut.result()


CLUSTER_CONNECT_TIMEOUT = 10.0  # s: a Dask scheduler must answer --cluster ADDRESS within this


def check_scheduler(address: str, timeout: float | None = None) -> None:
    """Raise ValueError naming `address` unless a Dask scheduler answers there within `timeout` s
    (default CLUSTER_CONNECT_TIMEOUT): a malformed address, nothing listening, a port that accepts
    and stays silent (distributed's Client would wait for ever) or one that speaks another protocol
    (its bytes read as Dask frame lengths: a request for exabytes) is bad input, not a hang."""
    import asyncio
    import concurrent.futures

    from distributed.comm import connect
    from distributed.core import send_recv

    timeout = CLUSTER_CONNECT_TIMEOUT if timeout is None else float(timeout)

    async def identity():
        comm = await connect(address, timeout=timeout)
        try:
            return await send_recv(comm, op="identity")
        finally:
            comm.abort()

    def probe():  # a fresh event loop in its own thread: safe when the caller runs one (Jupyter)
        return asyncio.run(asyncio.wait_for(identity(), timeout))

    what = f"--cluster {address!r}"
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=1)
    try:
        try:  # the thread's own deadline is `timeout`; the second is a backstop (a stuck name lookup)
            reply = pool.submit(probe).result(timeout=timeout + 5.0)
        except (asyncio.TimeoutError, concurrent.futures.TimeoutError, TimeoutError):
            raise ValueError(f"{what}: no Dask scheduler answered within {timeout:g} s (something listens there, "
                             "or the address is unreachable; give the scheduler's address, e.g. "
                             "tcp://HOST:8786, or 'local')") from None
        except MemoryError:  # another protocol's bytes read as a Dask frame length
            raise ValueError(f"{what}: something answered there, but not in Dask's protocol (not a Dask "
                             "scheduler); give the scheduler's address, e.g. tcp://HOST:8786, or 'local'") from None
        except Exception as exc:  # noqa: BLE001 - refused, unparsable, or not Dask's protocol
            raise ValueError(f"{what}: not a reachable Dask scheduler ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())[:200]}); give the scheduler's address, e.g. "
                             "tcp://HOST:8786, or 'local'") from None
    finally:
        pool.shutdown(wait=False)
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise ValueError(f"{what}: answered, but as {kind or type(reply).__name__}, not a Dask scheduler")


def _evaluate_dask(evaluate, cases, workers, cluster):
    require("distributed", "cluster", "--cluster")
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_completed

    local = None
    if cluster == "local":
        local = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True,
                             dashboard_address=None)
        client = Client(local)
    else:
        check_scheduler(cluster)  # Client() alone hangs on a silent port and trusts any bytes it reads
        client = Client(cluster, timeout=CLUSTER_CONNECT_TIMEOUT)
    try:
        futures = client.map(evaluate, cases, pure=False)
        index = {f.key: case for f, case in zip(futures, cases)}
        for fut in dask_completed(futures):
            yield index[fut.key], fut.result()
    finally:
        client.close()
        if local is not None:
            local.close()


# ---- one bench, end to end -------------------------------------------------------------------------

def _finite_or_none(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


def run(module: ModuleType, args: argparse.Namespace, command: str) -> dict:
    """Cases → rows (skipping those already in OUT/NAME.csv) → summary → charts. Returns the result
    that ``--json`` prints: ``{"command", "stamp", "rows", **module.summarize(rows), "resumed", "files"}``."""
    st = stamp(command)
    cases = module.cases(args)
    keys = [case_key(c, module.KEY_FIELDS) for c in cases]
    if len(set(keys)) != len(keys):
        raise RuntimeError(f"{module.NAME}: two cases share the key fields {module.KEY_FIELDS}")
    cluster = getattr(args, "cluster", None)
    if cluster is not None and not cluster.strip():
        raise ValueError("--cluster: empty address (give a Dask scheduler's address, or 'local')")
    if cluster and cluster != "local":  # before any file is touched
        require("distributed", "cluster", "--cluster")
        check_scheduler(cluster)
    done: dict[tuple, dict] = {}
    out = Path(args.out) if getattr(args, "out", None) else None
    appender = None
    if out is not None:
        if out.exists() and not out.is_dir():
            raise ValueError(f"--out {out}: not a folder")
        out.mkdir(parents=True, exist_ok=True)
        csv_path = out / f"{module.NAME}.csv"
        if csv_path.exists() and drop_partial_last_line(csv_path):
            print(f"{module.NAME}: {csv_path}: dropped a partial last line (an interrupted run); its case runs "
                  "again", file=sys.stderr)
        if csv_path.exists():
            wanted = set(keys)
            for row in read_csv(csv_path, tuple(module.FIELDS)):
                k = case_key(row, module.KEY_FIELDS)
                if k in wanted:
                    done[k] = row
        appender = _CsvAppender(csv_path, tuple(module.FIELDS))
    todo = [c for c, k in zip(cases, keys) if k not in done]
    workers = getattr(args, "workers", None) or getattr(module, "DEFAULT_WORKERS", None) or os.cpu_count() or 1
    new: dict[tuple, dict] = {}
    bar = _progress(len(todo), module.NAME)
    try:
        for case, row in evaluate_cases(module.evaluate, todo, workers, cluster):
            row = _check_row(module, case, row)
            new[case_key(case, module.KEY_FIELDS)] = row
            if appender is not None:
                appender.write(row)
            bar.update(1)
    finally:
        bar.close()
        if appender is not None:
            appender.close()
    rows = [done.get(k) or new[k] for k in keys]
    result = {"command": command, "stamp": st, "rows": rows}
    result.update(module.summarize(rows))
    result["resumed"] = len(done)
    if out is not None:
        files = [str(p) for p in module.plot(rows, out, st)]
        files.append(str(out / f"{module.NAME}.csv"))
        result["files"] = files
        stem = module.result_stem(args) if hasattr(module, "result_stem") else module.NAME
        saved = {k: v for k, v in result.items() if k != "rows"}  # the rows are the CSV's (not twice)
        saved["rows_csv"] = f"{module.NAME}.csv"
        with open(out / f"{stem}.json", "w") as fh:
            json.dump(_finite_or_none(saved), fh, indent=1, allow_nan=False)
            fh.write("\n")
    return _finite_or_none(result)
