"""Screenshot of the manual recovery of case 20 (issue 13), for the README.

    xvfb-run -a -s "-screen 0 1920x1080x24" env QT_QPA_PLATFORM=xcb \\
        LIBGL_ALWAYS_SOFTWARE=1 .venv/bin/python docs/screenshots/make_case20_shot.py \\
        ../shared/data/cases/20_real-palm1-pass2-pass5 1366x768 OUT.png

Six well-spread point pairs on points both scans hold (found with the truth, as a
technician finds them by eye; each snapped to the nearest scan point) become the
manual candidate; Accept coarse and Fine follow, and the overlay is saved.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np


def spread_pairs(target, source, T_true, k: int):
    """``k`` target points with a source point within 2 cm under the truth, spread by
    farthest-point order from the lowest one, and those source points."""
    from scipy.spatial import cKDTree

    d, j = cKDTree(source @ T_true[:3, :3].T + T_true[:3, 3]).query(target)
    shared = np.flatnonzero(d < 0.02)
    pts = target[shared]
    order = [int(np.argmin(pts[:, 2]))]
    far = np.linalg.norm(pts - pts[order[0]], axis=1)
    for _ in range(k - 1):
        order.append(int(np.argmax(far)))
        far = np.minimum(far, np.linalg.norm(pts - pts[order[-1]], axis=1))
    return target[shared[order]], source[j[shared[order]]]


def main(case: Path, size: str, out: Path) -> int:
    from amrst_gui.app import create_app

    app = create_app(sys.argv[:1])
    from PySide6.QtCore import QEventLoop, QSettings, QTimer

    from amrst.review.manual import fit_pairs
    from amrst.types import local_transform
    from amrst_gui.main_window import MainWindow

    QSettings.setPath(QSettings.IniFormat, QSettings.UserScope, tempfile.mkdtemp())
    win = MainWindow()
    w, _x, h = size.partition("x")
    win.resize(int(w), int(h))
    win.show()
    s = win.session
    s.discard_guard = None

    def run(start) -> None:
        loop = QEventLoop()
        s.busy_changed.connect(lambda busy: None if busy else loop.quit())
        start()
        if s.busy:
            loop.exec()
        loop2 = QEventLoop()
        QTimer.singleShot(500, loop2.quit)
        loop2.exec()

    run(lambda: s.load_scans(case / "target.ply", case / "source.ply"))
    s.load_truth(case / "truth.json")
    T_true = local_transform(s.truth, s.cloud("target"), s.cloud("source"))
    t, src = spread_pairs(s.cloud("target").xyz, s.cloud("source").xyz, T_true, 6)
    win.manual_panel.levelled.setChecked(False)  # 6 pairs: the full rigid fit
    for a, b in zip(t, src, strict=True):
        win.manual_panel.add_pair(a, b)
    run(win.manual_panel.use_pair_fit)
    run(s.accept_coarse)
    run(lambda: s.run_step("fine"))
    win.docks["manual"].raise_()
    run(lambda: None)
    win.grab().save(str(out))
    for stage, e in s.truth_errors().items():
        print(
            f"{stage}: {e.rotation_error_deg:.3f} deg, gt_rmse {e.gt_rmse_m * 100:.2f} cm"
        )
    print(s.fine_note)
    print(f"saved {out}")
    win.close()
    app.processEvents()
    fit = fit_pairs(t, src)
    print("pair residuals (mm):", np.round(fit.residuals_m * 1000, 1))
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])))
