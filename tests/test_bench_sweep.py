"""The sweep machinery every `stiction bench` shares: resumable CSV, row schema, stamps, and rows
that do not depend on where a case ran (this process, worker processes, a Dask LocalCluster)."""
import argparse
import csv
import json
import types

import pytest

from stiction.bench import scaling, sweep
from stiction.cli import main


def _toy_bench(calls):
    """A bench whose evaluate counts its calls: x -> x², one case per x."""
    m = types.ModuleType("toy")
    m.NAME, m.HELP = "toy", "toy"
    m.FIELDS, m.KEY_FIELDS, m.DEFAULT_WORKERS = ("x", "label", "square", "failed"), ("x", "label"), 1
    m.cases = lambda args: [{"x": x, "label": f"p{x}"} for x in args.xs]

    def evaluate(case):
        calls.append(case["x"])
        return {**case, "square": float(case["x"]) ** 2, "failed": case["x"] < 0}

    m.evaluate = evaluate
    m.summarize = lambda rows: {"total": sum(r["square"] for r in rows)}
    m.plot = lambda rows, out, st: []
    return m


def _args(tmp_path, xs, **kw):
    return argparse.Namespace(xs=xs, out=str(tmp_path), quick=False, cluster=None, workers=None, **kw)


def test_csv_holds_the_rows_and_a_second_run_resumes(tmp_path):
    calls = []
    bench = _toy_bench(calls)
    first = sweep.run(bench, _args(tmp_path, [1, 2, -3]), "stiction bench toy")
    assert calls == [1, 2, -3] and first["resumed"] == 0 and first["total"] == 14.0
    with open(tmp_path / "toy.csv") as fh:
        table = list(csv.reader(fh))
    assert table[0] == list(bench.FIELDS) and len(table) == 4
    assert table[3] == ["-3", "p-3", "9.0", "True"]
    second = sweep.run(bench, _args(tmp_path, [2, -3, 4]), "stiction bench toy")
    assert calls == [1, 2, -3, 4]  # only the new case ran
    assert second["resumed"] == 2 and [r["x"] for r in second["rows"]] == [2, -3, 4]
    assert second["rows"][1] == {"x": -3, "label": "p-3", "square": 9.0, "failed": True}  # read back typed
    saved = json.loads((tmp_path / "toy.json").read_text())
    assert saved["total"] == second["total"] and saved["stamp"]["command"] == "stiction bench toy"
    assert saved["rows_csv"] == "toy.csv" and "rows" not in saved  # the rows once, in the CSV


def test_an_interrupted_line_is_run_again_and_a_foreign_csv_is_refused(tmp_path):
    calls = []
    bench = _toy_bench(calls)
    (tmp_path / "toy.csv").write_text("x,label,square,failed\n1,p1,1.0,False\n2,p2\n")
    sweep.run(bench, _args(tmp_path, [1, 2]), "c")
    assert calls == [2]
    (tmp_path / "toy.csv").write_text("a,b\n")
    with pytest.raises(ValueError, match="not this bench's"):
        sweep.run(bench, _args(tmp_path, [1]), "c")


def test_a_row_that_breaks_the_schema_is_a_loud_error(tmp_path):
    bench = _toy_bench([])
    bench.evaluate = lambda case: {**case, "square": 1.0}  # no "failed"
    with pytest.raises(RuntimeError, match=r"missing \['failed'\]"):
        sweep.run(bench, _args(tmp_path, [1]), "c")
    bench.evaluate = lambda case: {**case, "x": 7, "square": 1.0, "failed": False}
    with pytest.raises(RuntimeError, match="key fields differ"):
        sweep.run(bench, _args(tmp_path, [1]), "c")


def test_stamp_names_machine_date_versions_and_command():
    st = sweep.stamp("stiction bench toy --quick")
    assert st["cores"] >= 1 and st["machine"] and st["date"].endswith("UTC")
    assert st["versions"]["pinocchio"].startswith("4.1") and "numpy" in st["versions"]
    text = sweep.stamp_text(st)
    assert "stiction bench toy --quick" in text and "pinocchio 4.1" in text


def _deterministic(rows):
    keep = ("scene", "layout", "contacts", "steps", "all_converged")
    return [{k: r[k] for k in keep} | {"rests": r["max_penetration"] <= 1e-9 and r["max_body_drift"] <= 1e-9}
            for r in rows]


def test_rows_do_not_depend_on_where_the_cases_ran(tmp_path, capsys):
    """The same scaling cases in this process, on two worker processes, and on a Dask LocalCluster."""
    argv = ["bench", "scaling", "--sizes", "4", "8", "--steps", "3", "--json"]
    here = []
    for extra in (["--workers", "1"], ["--workers", "2"], ["--cluster", "local", "--workers", "2"]):
        if extra[0] == "--cluster":
            pytest.importorskip("distributed")
        assert main(argv + extra) == 0
        here.append(_deterministic(json.loads(capsys.readouterr().out)["rows"]))
    assert here[0] == here[1] == here[2]
    assert [r["contacts"] for r in here[0]] == [4, 8] and all(r["rests"] for r in here[0])


def test_out_writes_csv_json_and_a_stamped_chart(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    assert main(["bench", "scaling", "--sizes", "4", "8", "--steps", "3", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "exponent" in printed
    assert (tmp_path / "scaling.png").stat().st_size > 10_000
    rows = sweep.read_csv(tmp_path / "scaling.csv", scaling.FIELDS)
    assert [r["contacts"] for r in rows] == [4, 8] and all(r["all_converged"] is True for r in rows)
    assert main(["bench", "scaling", "--sizes", "4", "8", "--steps", "3", "--out", str(tmp_path), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["resumed"] == 2 and [r["us_per_step"] for r in again["rows"]] == [r["us_per_step"] for r in rows]


def test_bench_all_needs_a_folder_and_unknown_benches_are_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "all"])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["bench", "speed"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_a_line_cut_mid_write_is_dropped_never_glued(tmp_path):
    """An interrupted sweep leaves its last row cut short, without a newline: resuming drops that
    fragment (its case runs again) and starts the next row on a line of its own."""
    calls = []
    bench = _toy_bench(calls)
    # the row of x = 2 cut after its first character: glued, "2" + "2,p2,4.0,False" would read as x = 22
    with open(tmp_path / "toy.csv", "w", newline="") as fh:
        fh.write("x,label,square,failed\r\n1,p1,1.0,False\r\n2")
    sweep.run(bench, _args(tmp_path, [1, 2, 3]), "c")
    assert calls == [2, 3]
    with open(tmp_path / "toy.csv", newline="") as fh:
        table = list(csv.reader(fh))
    assert table == [list(bench.FIELDS), ["1", "p1", "1.0", "False"], ["2", "p2", "4.0", "False"],
                     ["3", "p3", "9.0", "False"]]
    again = sweep.run(bench, _args(tmp_path, [1, 2, 3]), "c")
    assert calls == [2, 3] and again["resumed"] == 3  # nothing runs twice
    # a header cut short (the run stopped while writing it): the file starts over
    calls.clear()
    with open(tmp_path / "toy.csv", "w", newline="") as fh:
        fh.write("x,lab")
    sweep.run(bench, _args(tmp_path, [5]), "c")
    assert calls == [5]
    assert [r["x"] for r in sweep.read_csv(tmp_path / "toy.csv", bench.FIELDS)] == [5]
    # a complete file is left alone (a row ending in \r\n, or \n from another writer)
    before = (tmp_path / "toy.csv").read_bytes()
    assert not sweep.drop_partial_last_line(tmp_path / "toy.csv") and (tmp_path / "toy.csv").read_bytes() == before


def _run_main_in_thread(argv, limit):
    """main(argv) on a daemon thread: (finished within `limit` s, exit code)."""
    import threading

    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("code", main(argv)), daemon=True)
    worker.start()
    worker.join(limit)
    return not worker.is_alive(), result.get("code")


def test_cluster_that_is_not_a_dask_scheduler_is_refused_quickly(tmp_path, capsys, monkeypatch):
    """--cluster at a port that accepts and stays silent (Client() waited for ever), at one that
    answers in another protocol (its bytes read as a frame length: 'Unable to allocate 3.07 EiB'),
    and at malformed addresses: exit 2 with a message naming --cluster, before any file is written.
    Time is the subject (it used to hang): the bound is generous, the connect timeout 1 s here."""
    import socket
    import threading

    pytest.importorskip("distributed")
    monkeypatch.setattr(sweep, "CLUSTER_CONNECT_TIMEOUT", 1.0, raising=False)  # (absent before the check)
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)  # the kernel completes the handshake; nobody ever answers
    talker = socket.socket()
    talker.bind(("127.0.0.1", 0))
    talker.listen(8)
    talker.settimeout(30)

    def answer_in_http():
        try:
            while True:
                conn, _ = talker.accept()
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 4)
        except OSError:
            return

    threading.Thread(target=answer_in_http, daemon=True).start()
    try:
        for address in (f"tcp://127.0.0.1:{silent.getsockname()[1]}", f"127.0.0.1:{talker.getsockname()[1]}",
                        "garbage", "tcp://127.0.0.1:notaport", "http://127.0.0.1:8786", " "):
            out = tmp_path / "out"
            finished, code = _run_main_in_thread(["bench", "scaling", "--sizes", "4", "--steps", "3", "--json",
                                                  "--out", str(out), "--cluster", address], 30.0)
            assert finished, f"--cluster {address!r}: still connecting after 30 s"
            err = capsys.readouterr().err
            assert code == 2 and "--cluster" in err, (address, code, err)
            assert "internal error" not in err and "EiB" not in err
            assert not out.exists()  # refused before the folder or its CSV
    finally:
        silent.close()
        talker.close()


def test_cluster_at_a_real_scheduler_address_runs_and_a_worker_is_refused(capsys):
    """The connect check lets a scheduler through (an in-process LocalCluster's address) and
    refuses a Dask worker's address: it answers in Dask's protocol, but is not a scheduler."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        sweep.check_scheduler(cluster.scheduler_address, 5.0)
        worker = next(iter(cluster.workers.values())).address
        with pytest.raises(ValueError, match="as Worker, not a Dask scheduler"):
            sweep.check_scheduler(worker, 5.0)
        assert main(["bench", "scaling", "--sizes", "4", "--steps", "3", "--json",
                     "--cluster", cluster.scheduler_address]) == 0
        assert [r["contacts"] for r in json.loads(capsys.readouterr().out)["rows"]] == [4]
