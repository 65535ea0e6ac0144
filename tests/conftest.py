"""What every test must leave as it found it, checked after each test."""

import logging

import pytest

# ``ebad.progress`` decides from its level and handlers whether a phase line is logged or printed to stderr, so a
# test that leaves either changed makes a later test in the same worker miss its lines (CI on 92add60)
_WATCHED = ("ebad.progress", "scenes.colmap")


@pytest.fixture(autouse=True)
def _progress_loggers_left_as_found(request):
    loggers = [logging.getLogger(name) for name in _WATCHED]
    before = [(lg.level, lg.handlers[:], lg.propagate) for lg in loggers]
    yield
    for lg, (level, handlers, propagate) in zip(loggers, before):
        now = (lg.level, lg.handlers[:], lg.propagate)
        if now != (level, handlers, propagate):
            lg.setLevel(level)  # the next test starts clean either way
            lg.handlers[:], lg.propagate = handlers, propagate
            pytest.fail(
                f"{request.node.nodeid} left the logger {lg.name!r} changed: (level, handlers, propagate) "
                f"{(level, handlers, propagate)} -> {now}"
            )
