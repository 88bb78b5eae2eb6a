"""``amrst-gui`` without the app's libraries says which extra to install."""

from __future__ import annotations

import sys


def test_amrst_gui_without_pyside6_names_the_extra(monkeypatch, capsys):
    from amrst_gui.__main__ import main

    monkeypatch.setitem(sys.modules, "PySide6", None)  # import PySide6 fails
    assert main([]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1  # one line, no traceback
    assert "pip install 'amrst-studio[app]'" in err
