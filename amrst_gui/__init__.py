"""AMRST Studio: the desktop app."""
