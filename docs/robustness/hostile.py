"""Hostile corpus: a few hundred bad inputs and faults against ``amrst`` (issue 16).

Run from a checkout (``PYTHONPATH=. python docs/robustness/hostile.py``); give
``--code DIR`` to test another checkout (e.g. an older commit, for a before/after).
Every case runs in its own process with a 60 s limit and is classed as:

- ok       the expected outcome: exit 2 with one clear line (or 0 where the input is
           fine), outputs whole;
- crash    exit 1, a traceback or "Internal error";
- hang     still running after 60 s (killed);
- mixed    an output folder holding neither the complete old nor the complete new set,
           or debris left after the next run;
- unclear  exit 2 but not one line, raw library noise (warnings), or no hint of what
           to do; also exit 0 on input that must be refused.

Big inputs are generated here (sparse files, pipes, devices), nothing is shipped.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HINTS = (
    "give", "choose", "check", "use ", "fix", "remove", "convert", "update", "ask",
    "thin", "try", "copy", "point it", "let it", "wait", "rename", "export", "set ",
    "must be", "keep", "install", "select", "re-run", "split",
)  # fmt: skip
LIMIT_S = 60
MEMORY_BYTES = 3 << 30  # a run that reads /dev/zero must not take the machine down


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))


class Corpus:
    """Cases to run: (name, argv, expected exit codes, check of the outputs)."""

    def __init__(self, work: Path, code: Path) -> None:
        self.work, self.code = work, code
        self.sample = code / "resources" / "sample"
        self.tree = code / "tests" / "data" / "tiny_tree" / "tree.ply"
        self.cases: list[tuple[str, list[str], set[int], object]] = []
        self.n = 0

    def path(self, name: str) -> Path:
        self.n += 1
        folder = self.work / f"c{self.n}"
        folder.mkdir()
        return folder / name

    def add(self, name: str, argv: list[str], expect=frozenset({2}), check=None):
        self.cases.append((name, argv, set(expect), check))

    def register(self, *extra: str, out: Path | None = None) -> list[str]:
        out = out or self.path("out")
        return [
            "register", str(self.sample / "target.ply"),
            str(self.sample / "source.ply"), "--out", str(out), "--quiet", *extra,
        ]  # fmt: skip


def _special_paths(c: Corpus) -> dict[str, Path]:
    """Paths that are not regular files, made fresh for each use."""
    out: dict[str, Path] = {}
    fifo = c.path("pipe.json")
    os.mkfifo(fifo)
    out["fifo"] = fifo
    out["/dev/zero"] = Path("/dev/zero")
    out["/dev/urandom"] = Path("/dev/urandom")
    out["/dev/null"] = Path("/dev/null")
    sock = Path(tempfile.mktemp(prefix="amrst-h-", suffix=".sock", dir="/tmp"))
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(sock))
    s.close()
    out["socket"] = sock
    loop = c.path("loop.json")
    loop.symlink_to(loop.name)
    out["loop"] = loop
    dangling = c.path("dangling.json")
    dangling.symlink_to("nowhere.json")
    out["dangling link"] = dangling
    out["folder"] = c.path("dir")
    out["folder"].mkdir()
    blocker = c.path("file")
    blocker.write_text("x")
    out["through a file"] = blocker / "x.json"
    out["missing"] = c.path("missing.json")
    out["long name"] = c.path("a" * 300 + ".json")
    return out


def _json_files(c: Corpus) -> dict[str, Path]:
    """Files with hostile JSON content."""
    rigid = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    texts = {
        "deep brackets": "[" * 100_000 + "]" * 100_000,
        "deep objects": '{"a":' * 50_000 + "1" + "}" * 50_000,
        "5000-digit int": '{"T_target_source": ' + "9" * 5000 + "}",
        "4000-digit int": '{"fine": {"max_iterations": ' + "9" * 4000 + "}}",
        "1e400": '{"fine": {"max_corr_dist_m": 1e400}}',
        "NaN": '{"fine": {"max_corr_dist_m": NaN}}',
        "-Infinity": '{"fine": {"max_corr_dist_m": -Infinity}}',
        "empty": "",
        "whitespace": "   \n\t ",
        "truncated": '{"T_target_source": [[1, 0, 0',
        "array": "[1, 2, 3]",
        "string": '"hello"',
        "null": "null",
        "binary": "\x00\x01\x02\xff",
        "T 3x3": json.dumps({"T_target_source": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}),
        "T scaled": json.dumps({"T_target_source": [[2, 0, 0, 0], [0, 2, 0, 0],
                                                    [0, 0, 2, 0], [0, 0, 0, 1]]}),
        "T strings": json.dumps({"T_target_source": [["1"] * 4] * 4}),
        "T 1e300": json.dumps({"T_target_source": [[*r[:3], 1e+300 if i == 0 else 0]
                                                   for i, r in enumerate(rigid)]}),
        "T 1e9": json.dumps({"T_target_source": [[*r[:3], 1000000000.0 if i == 0 else 0]
                                                 for i, r in enumerate(rigid)]}),
        "T bools": json.dumps({"T_target_source": [[True] * 4] * 4}),
        "unknown section": '{"nonsense": {}}',
        "schema 99": '{"schema_version": 99}',
        "scales_k 1e8": '{"separate": {"scales_k": [100000000]}}',
        "scales_k many": '{"separate": {"scales_k": [' + ",".join(["10"] * 1000) + "]}}",
        "scales_k empty": '{"separate": {"scales_k": []}}',
        "seed huge": '{"coarse": {"seed": ' + "9" * 100 + "}}",
        "duplicate keys": '{"fine": {"method": "icp", "method": "???"}}',
    }  # fmt: skip
    out = {}
    for name, text in texts.items():
        p = c.path("f.json")
        p.write_text(text, encoding="utf-8", errors="surrogateescape")
        out[name] = p
    bom = c.path("bom.json")
    bom.write_bytes(b"\xef\xbb\xbf{}")
    out["UTF-8 BOM"] = bom
    utf16 = c.path("utf16.json")
    utf16.write_text("{}", encoding="utf-16")
    out["UTF-16"] = utf16
    huge = c.path("huge.json")
    with huge.open("wb") as f:
        f.truncate(200_000_000)  # sparse: no disk used
    out["200 MB sparse"] = huge
    return out


def _param_values(c: Corpus) -> None:
    """Every parameter out of range, of the wrong type, huge, not finite."""
    sys.path.insert(0, str(c.code))
    import dataclasses

    from amrst.params import RegistrationParams

    params = RegistrationParams()
    for f in dataclasses.fields(params):
        stage = getattr(params, f.name)
        for g in dataclasses.fields(stage):
            meta, default = g.metadata, getattr(stage, g.name)
            bad: list[object] = ["text", [1, 2]]
            if "min" not in meta and "max" not in meta and "choices" not in meta:
                continue  # free values (e.g. an intensity threshold): any number goes
            if isinstance(default, (int, float)) and not isinstance(default, bool):
                if "max" in meta:
                    bad.append(meta["max"] * 10 + 1)
                if "min" in meta:
                    bad.append(meta["min"] - 1)
                bad.append(10**30)
            for value in bad:
                p = c.path("p.json")
                p.write_text(json.dumps({f.name: {g.name: value}}))
                c.add(f"--params {f.name}.{g.name}={str(value)[:12]}",
                      c.register("--params", str(p)))  # fmt: skip


def _snapshot(folder: Path) -> dict[str, bytes]:
    if not folder.is_dir():
        return {}
    return {
        p.name: p.read_bytes()
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".")
    }


def _drop_volatile(value: object) -> object:
    """A document without what differs between two identical runs (times)."""
    if isinstance(value, dict):
        return {
            k: _drop_volatile(v)
            for k, v in value.items()
            if k not in ("created", "timings_s", "read")
        }
    return value


def _strip(files: dict[str, bytes]) -> dict[str, object]:
    """The content of a set, without times (creation, timings)."""
    out: dict[str, object] = {}
    for name, data in files.items():
        if name.endswith(".json"):
            out[name] = _drop_volatile(json.loads(data))
        elif name.endswith(".csv"):
            out[name] = [r for r in data.splitlines() if b"timings_s." not in r]
        else:
            out[name] = data
    return out


def build(c: Corpus) -> None:
    """All the cases but the kill/concurrency faults."""
    special = _special_paths(c)
    for opt in ("--truth", "--params", "--out"):
        c.add(f"{opt} empty path", c.register(opt, "") if opt != "--out" else [
            "register", str(c.sample / "target.ply"), str(c.sample / "source.ply"),
            "--out", ""])  # fmt: skip
    c.add("simulate --out empty path", ["simulate", str(c.tree), "--out", ""])
    for kind, path in special.items():
        for opt in ("--truth", "--params"):
            c.add(f"{opt} {kind}", c.register(opt, str(path)))
        if kind not in ("folder", "missing", "/dev/null"):
            c.add(f"--out {kind}", c.register(out=path))
            c.add(f"simulate --out {kind}",
                  ["simulate", str(c.tree), "--out", str(path)])  # fmt: skip
        c.add(f"info {kind}", ["info", str(path)])
        c.add(f"register TARGET={kind}",
              ["register", str(path), str(c.sample / "source.ply"),
               "--out", str(c.path("out")), "--quiet"])  # fmt: skip
        c.add(f"simulate TREE={kind}",
              ["simulate", str(path), "--out", str(c.path("case"))])  # fmt: skip
    for kind, path in _json_files(c).items():
        for opt in ("--truth", "--params"):
            expect = {0, 3} if kind in ("UTF-8 BOM",) and opt == "--params" else {2}
            c.add(f"{opt} {kind}", c.register(opt, str(path)), expect)
    _param_values(c)
    for opt, values in {
        "--noise-m": ["1e300", "1e6", "-1", "nan", "inf"],
        "--res-deg": ["0", "-1", "nan", "1e300"],
        "--distance-m": ["0", "-5", "nan", "1e300"],
        "--tilt-deg": ["1e300", "nan", "-1"],
        "--separation-deg": ["nan", "inf"],
        "--seed": ["-1", "x"],
    }.items():
        for v in values:
            c.add(f"simulate {opt} {v}",
                  ["simulate", str(c.tree), "--out", str(c.path("case")), opt, v])  # fmt: skip
    for opt, v in (("--format", "e57"), ("--preset", "nope")):
        c.add(f"register {opt} {v}", c.register(opt, v))
    api = {
        "Cloud offset inf": "Cloud(np.zeros((5,3)), offset=[np.inf,0,0])",
        "Cloud offset nan": "Cloud(np.zeros((5,3)), offset=[0,np.nan,0])",
        "Cloud offset 2 values": "Cloud(np.zeros((5,3)), offset=[0,0])",
        "Cloud xyz (5,2)": "Cloud(np.zeros((5,2)))",
        "register offset inf": "amrst.register(t, Cloud(t.xyz, offset=[np.inf,0,0]))",
        "register empty source": "amrst.register(t, Cloud(np.zeros((0,3))))",
        "register 3 points": "amrst.register(t, Cloud(np.eye(3)))",
        "register identical points": "amrst.register(t, Cloud(np.ones((5000,3))))",
        "read_truth fifo": f"read_truth({str(special['fifo'])!r})",
        "load_params /dev/zero": "load_params('/dev/zero')",
    }
    for name, expr in api.items():
        code = (
            "import sys, numpy as np, amrst; from amrst import io; "
            "from amrst.types import Cloud; from amrst.io.truth import read_truth; "
            "from amrst.params import load_params\n"
            f"t = io.read({str(c.sample / 'target.ply')!r})\n"
            f"try:\n    r = {expr}\nexcept amrst.AmrstError as e:\n"
            "    print('Error:', e, file=sys.stderr); sys.exit(2)\n"
            "T = getattr(r, 'T_target_source', None)\n"
            "if T is not None and not np.isfinite(T).all(): sys.exit(1)\n"
        )
        c.add(f"API {name}", ["-c", code])


def run_one(c: Corpus, argv: list[str], env: dict[str, str]):
    cmd = [sys.executable, *argv] if argv[0] == "-c" else [
        sys.executable, "-m", "amrst.cli", *argv]  # fmt: skip
    start = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=LIMIT_S,
                           env=env, errors="replace", check=False,
                           preexec_fn=_limit_memory)  # fmt: skip
    except subprocess.TimeoutExpired:
        return None, "", time.monotonic() - start
    return p.returncode, p.stderr, time.monotonic() - start


def classify(code, err: str, expect: set[int]) -> str:
    if code is None:
        return "hang"
    if code == 1 or code < 0 or "Traceback" in err or "Internal error" in err:
        return "crash"
    if code not in expect:
        return "unclear"
    if code == 2:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if lines and lines[0].startswith("usage:") and "error: argument" in lines[-1]:
            return "ok"  # argparse: the usage and what is wrong with the option
        low = err.lower()
        if "out of memory" in low:
            return "unclear"  # no input here is big: memory ran out on a bad value
        if len(lines) != 1 or "warning" in low or not any(h in low for h in HINTS):
            return "unclear"
    return "ok"


def faults(c: Corpus, env: dict[str, str], rng: random.Random) -> list[tuple[str, str]]:
    """Kills at random instants and concurrent writers, on real register runs."""
    results = []
    base = c.register("--write-clouds", out=c.path("ref_old"))
    run_one(c, base, env)
    old = _strip(_snapshot(Path(base[4])))
    new_args = c.register("--write-clouds", "--format", "pcd", out=c.path("ref_new"))
    t0 = time.monotonic()
    run_one(c, new_args, env)
    runtime = time.monotonic() - t0
    new = _strip(_snapshot(Path(new_args[4])))
    for i in range(24):
        out = c.path("out")
        shutil.copytree(base[4], out)
        argv = c.register("--write-clouds", "--format", "pcd", out=out)
        p = subprocess.Popen([sys.executable, "-m", "amrst.cli", *argv], env=env,
                             stderr=subprocess.DEVNULL, stdout=subprocess.DEVNULL)  # fmt: skip
        time.sleep(rng.uniform(0.6, 1.0) * runtime)
        p.send_signal(signal.SIGKILL)
        p.wait()
        now = _strip(_snapshot(out))
        verdict = "ok" if now in (old, new) else "mixed"
        run_one(c, c.register(out=out), env)  # the next run clears the debris
        debris = [x.name for x in out.iterdir() if x.name.startswith(".")]
        debris += [x.name for x in out.parent.iterdir() if "amrst-swap" in x.name]
        if debris:
            verdict = "mixed"
        results.append((f"SIGKILL register at {i}", verdict))
    for i in range(3):
        out = c.path("out")
        argv = [c.register("--write-clouds", out=out),
                c.register("--write-clouds", "--format", "pcd", out=out)]  # fmt: skip
        procs = [subprocess.Popen([sys.executable, "-m", "amrst.cli", *a], env=env,
                                  stderr=subprocess.PIPE, text=True) for a in argv]  # fmt: skip
        codes = [p.wait(timeout=300) for p in procs]
        now = _strip(_snapshot(out))
        ok = codes == [0, 0] and now in (old, new)
        results.append((f"two writers {i}", "ok" if ok else "mixed"))
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--code", default=".", help="checkout to test")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-faults", action="store_true")
    ap.add_argument("--seed", type=int, default=16)
    args = ap.parse_args()
    code = Path(args.code).resolve()
    env = {**os.environ, "PYTHONPATH": str(code), "PYTHONWARNINGS": "default"}
    work = Path(tempfile.mkdtemp(prefix="amrst-hostile-"))
    c = Corpus(work, code)
    try:
        build(c)
        with ThreadPoolExecutor(args.jobs) as pool:
            runs = list(pool.map(lambda case: run_one(c, case[1], env), c.cases))
        verdicts = []
        for (name, _, expect, _), (rc, err, _) in zip(c.cases, runs, strict=False):
            v = classify(rc, err, expect)
            verdicts.append((name, v))
            if v != "ok":
                line = err.strip().splitlines()[-1][:160] if err.strip() else ""
                print(f"{v:8s} {name}: exit {rc}: {line}")
        if not args.no_faults:
            for name, v in faults(c, env, random.Random(args.seed)):
                verdicts.append((name, v))
                if v != "ok":
                    print(f"{v:8s} {name}")
        counts = {k: sum(v == k for _, v in verdicts)
                  for k in ("ok", "crash", "hang", "mixed", "unclear")}  # fmt: skip
        print(
            f"{len(verdicts)} cases: "
            + ", ".join(f"{k} {n}" for k, n in counts.items())
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)
        for sock in Path("/tmp").glob("amrst-h-*.sock"):
            sock.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
