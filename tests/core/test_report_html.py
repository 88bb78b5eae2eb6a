"""``amrst register --report``: one self-contained HTML file, pictures drawn without a
display (matplotlib Agg), the verdict and why; a poor stem-slice fit says so."""

from __future__ import annotations

import base64
import re
import subprocess
import sys

import numpy as np

from amrst.cli import main


def test_register_report_holds_the_verdict_and_embedded_pictures(
    sample_pair, tmp_path, capsys
) -> None:
    out = tmp_path / "out"
    args = [
        "register",
        str(sample_pair.target_path),
        str(sample_pair.source_path),
        "--out",
        str(out),
        "--truth",
        str(sample_pair.truth_path),
        "--report",
        "--quiet",
    ]
    assert main(args) == 0
    assert "report.html" in capsys.readouterr().out
    html = (out / "report.html").read_text(encoding="utf-8")
    assert ">Registered<" in html
    assert "Why:" in html
    assert "Next:" in html
    pngs = re.findall(r'<img [^>]*src="data:image/png;base64,([^"]+)"', html)
    assert len(pngs) == 4
    assert all(base64.b64decode(p).startswith(b"\x89PNG") for p in pngs)
    # The truth errors of the fine result: under 1 cm on the sample.
    row = re.search(
        r"Truth: point error RMS</td><td>([\d.]+) cm</td><td>([\d.]+) cm", html
    )
    assert row is not None
    assert float(row.group(2)) < 1.0


def test_report_modules_need_no_display_nor_qt() -> None:
    # The report is drawn in a process where Qt and pyvista cannot be imported.
    code = (
        "import sys; sys.modules['PySide6'] = None; sys.modules['pyvista'] = None\n"
        "import amrst.report_html, amrst.report_images\n"
        "from amrst.report_images import slices_png\n"
        "assert slices_png([]).startswith(b'\\x89PNG')\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_slice_through_a_flared_base_says_the_fit_is_unreliable() -> None:
    from amrst.quality import stem_slices

    rng = np.random.default_rng(0)

    def ring(r, n, z0, z1, arc=2 * np.pi):
        a = rng.uniform(0, arc, n)
        return np.c_[r * np.cos(a), r * np.sin(a), rng.uniform(z0, z1, n)]

    # A 12 cm stem from 0 to 4 m; near the ground a few points of roots on a wide
    # ring (one scan sees one side of it) and scattered litter.
    stem = ring(0.12, 3000, 0, 4)
    target = np.vstack(
        [
            stem,
            ring(0.5, 30, 0.25, 0.35, arc=4),
            rng.uniform([-0.6, -0.6, 0.25], [0.6, 0.6, 0.35], (150, 3)),
        ]
    )
    source = target + rng.normal(0, 0.002, target.shape)
    slices = stem_slices(target, source, (0.3, 1.3))
    assert slices[0].problem().startswith("fit unreliable")
    assert "points" in slices[0].caption()[1]
    assert "mm apart" not in slices[0].caption()[1]
    assert slices[1].problem() == ""
    assert slices[1].caption()[1].endswith("mm apart")
