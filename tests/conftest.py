import jax
import pytest


jax.config.update("jax_enable_x64", True)


def _runtime_type_checks(config) -> bool:
    """Whether jaxtyping's import hook checks brdfscale's annotations at run time in this session
    (``--jaxtyping-packages=brdfscale,…``, .ci/run's second pass of the default suite)."""
    try:
        packages = config.getoption("--jaxtyping-packages")
    except ValueError:  # jaxtyping's pytest plugin is not installed
        return False
    return bool(packages) and "brdfscale" in str(packages).split(",")


def pytest_collection_modifyitems(config, items):
    """With runtime type checks on, tests marked ``wrong_types`` are deselected: they hand a public
    function an argument of a type its annotation excludes, to check the library's own error message
    (what a user without the checks sees); with the checks on, the annotation's check answers first
    with jaxtyping's TypeCheckError naming the parameter, which is the purpose of those checks. The
    same tests run, with their assertions, in the suite without the checks."""
    if not _runtime_type_checks(config):
        return
    kept, dropped = [], []
    for item in items:
        (dropped if item.get_closest_marker("wrong_types") else kept).append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = kept


@pytest.fixture(autouse=True)
def _no_persistent_compilation_cache(request, monkeypatch):
    """The ``brdfscale`` command switches on JAX's persistent compilation cache, a process-wide
    setting: tests that call the command in-process run without it (it would stay on for the
    rest of the session and write into the user's cache directory). Tests marked
    ``compilation_cache`` exercise it themselves."""
    if request.node.get_closest_marker("compilation_cache") is None:
        monkeypatch.setattr("brdfscale._compilation_cache.enable", lambda directory=None: None)


def pytest_runtest_teardown(item, nextitem):
    """After a slow study's last test in a module (``-m slow``, .ci/run's last step), JAX's caches of
    compiled programs are emptied. A long-lived xdist worker otherwise keeps every program it
    compiled, each with its executable memory mappings (about three per program, which
    ``jax.clear_caches`` releases: measured with /proc/self/maps), and one such worker failed with
    "LLVM compilation error: Cannot allocate memory" late in a clean-clone run: the kernel's
    ``vm.max_map_count`` (65 530 there) bounds a process's mappings. Not in the default suite, whose
    modules share compiled programs and whose time is budgeted."""
    if nextitem is not None and nextitem.module is item.module:
        return
    if item.get_closest_marker("slow") is not None:
        jax.clear_caches()
