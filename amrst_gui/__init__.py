"""AMRST Studio: the desktop app.

qtpy (used by superqt and pyvistaqt) must pick the same binding as our own
``PySide6`` imports, so ``QT_API`` is set here, before any submodule imports them.
"""

import os

os.environ.setdefault("QT_API", "pyside6")
