import jax
import pytest


jax.config.update("jax_enable_x64", True)


@pytest.fixture(autouse=True)
def _no_persistent_compilation_cache(request, monkeypatch):
    """The ``brdfscale`` command switches on JAX's persistent compilation cache, a process-wide
    setting: tests that call the command in-process run without it (it would stay on for the
    rest of the session and write into the user's cache directory). Tests marked
    ``compilation_cache`` exercise it themselves."""
    if request.node.get_closest_marker("compilation_cache") is None:
        monkeypatch.setattr("brdfscale._compilation_cache.enable", lambda directory=None: None)
