"""Inputs that once ended the process inside a compiled library: each case runs in a
child process, so a regression fails its test (a signal, or a wrong exit code)
instead of killing the suite. Exit code 2: refused input; 3: no registration.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import amrst
from amrst import io
from amrst.errors import InvalidInput
from amrst.guards import feature_points, grid_pair, kiss_pair, require_points
from amrst.resources import resource_path

CASE = str(resource_path("sample"))  # the bundled pair: a real tree from two scans

PRELUDE = """
import sys
import numpy as np
from amrst.errors import AmrstError, InvalidInput, RegistrationFailed

def finish(fn):
    try:
        print(fn())
    except InvalidInput as exc:
        print(exc, file=sys.stderr)
        sys.exit(2)
    except RegistrationFailed as exc:
        print(exc, file=sys.stderr)
        sys.exit(3)
"""


def run_child(body: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run ``body`` (after PRELUDE) in a fresh interpreter; never raise on its exit."""
    code = PRELUDE + textwrap.dedent(body)
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def assert_exit(proc: subprocess.CompletedProcess[str], codes: tuple[int, ...]) -> None:
    assert proc.returncode >= 0, f"killed by signal {-proc.returncode}: {proc.stderr}"
    assert proc.returncode in codes, (proc.returncode, proc.stdout, proc.stderr)
    assert "voxel coord is out of range" not in proc.stderr


def _tree(n: int = 3000, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0, 1, (n, 3)) * [5, 5, 20]


# --- the guards themselves, in this process (they never call compiled code) -------


def test_require_points_refuses_empty_and_nan():
    with pytest.raises(InvalidInput, match="0 point"):
        require_points(np.zeros((0, 3)), "the source scan")
    with pytest.raises(InvalidInput, match="NaN"):
        require_points(np.array([[0.0, np.nan, 1.0]]), "the source scan")


def test_grid_pair_moves_far_clouds_and_undoes_it():
    xyz = _tree() + 5e5  # beyond +-2**20 voxels of 0.1 m about the origin
    pair = grid_pair(xyz, xyz + np.array([1.0, 2.0, 3.0]), 0.1)
    assert np.abs(pair.target).max() < 2**20 * 0.1
    assert np.abs(pair.source).max() < 2**20 * 0.1
    assert np.allclose(pair.target + pair.target_shift, xyz)
    assert np.allclose(pair.source + pair.source_shift, xyz + np.array([1.0, 2.0, 3.0]))
    # identity between the moved clouds: the source's shift out, the target's in
    T = pair.unshift(np.eye(4))
    assert np.allclose(T[:3, 3], pair.target_shift - pair.source_shift)
    near = grid_pair(_tree(), _tree(), 0.1)  # within the grid: left as it is
    assert not near.target_shift.any()
    assert not near.source_shift.any()


def test_grid_pair_refuses_a_span_the_grid_cannot_hold():
    xyz = _tree()
    xyz[:, 0] = np.linspace(0, 1e6, len(xyz))
    with pytest.raises(
        InvalidInput, match=r"the source scan spans 1e\+06 m.*amrst clip"
    ):
        grid_pair(_tree(), xyz, 0.1)


def test_kiss_pair_skips_clouds_without_features():
    sparse = np.random.default_rng(0).uniform(0, 1e4, (1000, 3))
    assert feature_points(sparse, 0.1, 0.3) == 0
    assert kiss_pair(_tree(), sparse, 0.1, 0.3) is None
    assert kiss_pair(_tree(), _tree(seed=1), 0.1, 0.3) is not None


def test_cloud_refuses_nan_and_absurd_coordinates():
    with pytest.raises(InvalidInput, match="NaN/inf"):
        amrst.Cloud(np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(InvalidInput, match="1e\\+15 m"):
        amrst.Cloud(_tree() + 1e15)
    amrst.Cloud(_tree() + 6.4e6, offset=[5e5, 5e6, 0])  # ECEF-sized: fine


# --- the compiled libraries, in a child process -----------------------------------


@pytest.mark.parametrize(
    "source",
    [
        "np.random.default_rng(0).uniform(0, 1e4, (1000, 3))",  # no neighbours
        "base[:5]",  # too few points
        "np.zeros((100, 3))",  # one point, repeated
        "np.column_stack([np.linspace(0, 1e5, 3000), base[:, 1:]])",  # 1e5 m spread
        "base + 5e8",  # beyond the voxel keys
    ],
)
def test_kiss_matcher_behind_its_guard_never_dies(source):
    pytest.importorskip("kiss_matcher")
    proc = run_child(
        f"""
        import kiss_matcher
        from amrst.guards import kiss_pair
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        source = {source}

        def go():
            cfg = kiss_matcher.KISSMatcherConfig(0.1)
            pair = kiss_pair(base, source, 0.1, cfg.normal_radius)
            if pair is None:
                return "skipped"
            sol = kiss_matcher.KISSMatcher(cfg).estimate(
                pair.source.astype(np.float32), pair.target.astype(np.float32)
            )
            return f"ran {{sol.valid}}"

        finish(go)
        """
    )
    assert_exit(proc, (0, 2))


@pytest.mark.parametrize("case", ["empty", "far", "nan"])
def test_small_gicp_behind_its_guard_never_dies(case):
    pytest.importorskip("small_gicp")
    proc = run_child(
        f"""
        import small_gicp
        from amrst.guards import grid_pair
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        other = {{"empty": np.zeros((0, 3)), "far": base + 1e7,
                  "nan": np.vstack([base, [[np.nan] * 3]])}}["{case}"]

        def go():
            pair = grid_pair(other, base, 0.02)  # an empty target ended the process
            res = small_gicp.align(pair.target, pair.source, np.eye(4),
                                   registration_type="GICP",
                                   downsampling_resolution=0.02,
                                   max_correspondence_distance=0.2, num_threads=1)
            T = pair.unshift(res.T_target_source)
            assert np.allclose(T[:3, 3], other.mean(axis=0) - base.mean(axis=0),
                               atol=0.05), T
            return "ok"

        finish(go)
        """
    )
    assert_exit(proc, (0, 2) if case == "far" else (2,))
    if case == "far":
        assert proc.stdout.strip() == "ok"


def test_register_api_with_absurd_coordinates_is_refused():
    proc = run_child(
        f"""
        import amrst
        from amrst.io import read
        T = read("{CASE}/target.ply")
        finish(lambda: amrst.register(T, amrst.Cloud(T.xyz + 1e15)))
        """
    )
    assert_exit(proc, (2,))
    assert "1e+15 m" in proc.stderr
    assert proc.stderr.count("\n") == 1


@pytest.mark.parametrize("spread", ["all", "scaled"])
def test_register_cli_on_a_source_spread_over_1e6_m(tmp_path, spread):
    source = io.read(f"{CASE}/source.ply")
    xyz = source.xyz.copy()
    if spread == "all":
        xyz[:, 0] = np.random.default_rng(0).uniform(0, 1e6, len(xyz))
    else:
        xyz *= 1e5
    io.write(tmp_path / "source.ply", amrst.Cloud(xyz))
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "amrst.cli",
            "register",
            f"{CASE}/target.ply",
            str(tmp_path / "source.ply"),
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert_exit(proc, (2, 3))
    error = [
        line for line in proc.stderr.splitlines() if line.startswith("amrst register:")
    ]
    assert len(error) == 1, proc.stderr


def test_e57_that_is_not_e57_is_one_line(tmp_path):
    bad = tmp_path / "scan.e57"
    bad.write_bytes(b"PK\x03\x04 a zip file, not a scan" * 40)
    proc = subprocess.run(
        [sys.executable, "-m", "amrst.cli", "info", str(bad)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert_exit(proc, (2,))
    assert proc.stderr.count("\n") == 1
    assert "not a readable E57 file" in proc.stderr
    assert "Debug info" not in proc.stderr


# --- each call site of a compiled library, with the input that ended it ------------

FAR_SOURCES = {
    "empty": "np.zeros((0, 3))",
    "sparse": "np.random.default_rng(0).uniform(0, 1e4, (1000, 3))",  # no features
    "far": "base + 1e7",  # beyond small_gicp's 2 cm voxel keys
    "wide": "np.column_stack([np.linspace(0, 1e6, 3000), base[:, 1:]])",
}


@pytest.mark.parametrize("source", sorted(FAR_SOURCES))
def test_bench_peer_never_dies(source):
    pytest.importorskip("kiss_matcher")
    pytest.importorskip("small_gicp")
    proc = run_child(
        f"""
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        from amrst.bench.kiss import kiss_gicp, peer_input
        source = {FAR_SOURCES[source]}

        def go():
            T = kiss_gicp(peer_input(base, source))
            assert np.isfinite(T).all(), T
            if "{source}" == "far":  # GICP from the identity, within its reach
                move = base.mean(axis=0) - source.mean(axis=0)
                assert np.allclose(T[:3, 3], move, atol=0.01), T
            return "ok"

        finish(go)
        """
    )
    assert_exit(proc, (2,) if source in ("empty", "wide") else (0,))


@pytest.mark.parametrize("case", ["empty_target", "empty_source", "far", "nan"])
def test_baseline_refine_gicp_never_dies(case):
    pytest.importorskip("small_gicp")
    proc = run_child(
        f"""
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        from amrst.baselines.kiss_matcher import KissParams, refine_gicp
        target, source = {{
            "empty_target": (np.zeros((0, 3)), base),  # ended the process
            "empty_source": (base, np.zeros((0, 3))),
            "far": (base + 1e7, base),  # its points dropped by the voxel grid
            "nan": (base, np.vstack([base, [[np.nan] * 3]])),
        }}["{case}"]
        T0 = np.eye(4)
        T0[:3, 3] = 1e7 if "{case}" == "far" else 0.0

        def go():
            T = refine_gicp(target, source, T0, KissParams())
            assert np.allclose(T[:3, 3], T0[:3, 3], atol=0.01), T
            return "ok"

        finish(go)
        """
    )
    assert_exit(proc, (0,) if case == "far" else (2,))
    assert proc.stderr.count("\n") <= 1


@pytest.mark.parametrize("build", ["knn", "nearest", "table"])
@pytest.mark.parametrize("points", ["empty", "nan", "inf"])
def test_kd_tree_builds_never_die(build, points):
    proc = run_child(
        f"""
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        import pickle
        from amrst.neighbours import NearestTree, NeighbourTable, knn
        points = {{"empty": np.zeros((0, 3)), "nan": base.copy(), "inf": base.copy()}}[
            "{points}"
        ]
        if len(points):
            points[7] = np.nan if "{points}" == "nan" else np.inf

        def go():
            if "{build}" == "knn":
                return knn(points, 1, base[:5])[1].ravel()
            if "{build}" == "table":
                return NeighbourTable.build(points, 8).knn(4)[1][:2]
            # a tree sent to another process is built again where it is queried
            tree = pickle.loads(pickle.dumps(NearestTree(points)))
            return tree.query(base[:5])[1]

        finish(go)
        """
    )
    if points == "empty" and build == "nearest":  # no tree: every query finds none
        assert_exit(proc, (0,))
        assert proc.stdout.split() == ["[0", "0", "0", "0", "0]"]
    elif points == "empty":  # a k no cloud of no points can give: the caller's bug
        assert proc.returncode == 1, proc.stderr
        assert "ValueError" in proc.stderr
    else:
        assert_exit(proc, (2,))
        assert "the cloud searched for neighbours holds NaN or infinite" in proc.stderr


WIDE = "base * [5e7, 1, 1]"  # a 2.5e8 m span: beyond Open3D's voxel keys

OPEN3D_CASES = {
    # Open3D raised a RuntimeError ("voxel_size is too small") with its source path
    "icp_wide": f"b.register_icp(Cloud(base), Cloud({WIDE}))",
    "fpfh_wide": f"b.register_fpfh_ransac(Cloud({WIDE}), Cloud(base))",
    "refine_wide": f"features.refine_point_to_plane(base, {WIDE}, np.eye(4), params)",
    # ... and on FPFH features of no points
    "fgr_empty": "features.global_ransac(base, np.zeros((0, 3)), params)",
}


@pytest.mark.parametrize("case", sorted(OPEN3D_CASES))
def test_open3d_baselines_refuse_in_one_line(case):
    pytest.importorskip("open3d")
    proc = run_child(
        f"""
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        import amrst.baselines as b
        from amrst.baselines import features
        from amrst.types import Cloud
        params = features.FeatureParams()
        finish(lambda: {OPEN3D_CASES[case]})
        """
    )
    assert_exit(proc, (2,))
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert "Open3D" not in proc.stderr


def test_robust_plane_on_an_empty_target_is_one_line():
    pytest.importorskip("open3d")
    proc = run_child(
        """
        base = np.random.default_rng(1).uniform(0, 1, (3000, 3)) * [5, 5, 20]
        from amrst.stages.fine import FineParams, refine_registration
        params = FineParams(method="robust_plane")
        # Open3D's point-to-plane ICP raised its own error here (no target normals)
        finish(lambda: refine_registration(np.zeros((0, 3)), base, np.eye(4), params))
        """
    )
    assert_exit(proc, (2,))
    assert "the target scan has 0 point(s)" in proc.stderr
