"""Shared fixtures."""
import pytest


@pytest.fixture
def monkeypatch(monkeypatch):
    """pytest's ``monkeypatch``, after the compiled kernels of every kind of problem are loaded:
    ``solve`` loads a kind's kernels by solving representative problems the first time it meets
    the kind (``solvers.kernel_loading``), and those solves must not run through a test's
    patched routes (a test that then passes only after another test loaded its kind)."""
    import solvers
    solvers.load_kernels()      # (once a session; later calls find every kind loaded)
    return monkeypatch
