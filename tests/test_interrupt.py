"""gtvo.core.interrupt: a Ctrl-C that a library swallows is still seen by the run."""

import signal

import pytest

from gtvo.core import interrupt


@pytest.fixture(autouse=True)
def _reset():
    interrupt._interrupted = False
    yield
    interrupt._interrupted = False


def test_a_swallowed_interrupt_is_raised_again():
    assert not interrupt.interrupt_requested()
    interrupt.raise_if_interrupted()  # nothing seen: no-op
    try:  # a library that catches everything (matplotlib's optional import, a weakref callback)
        interrupt.note_interrupt(signal.SIGINT, None)
    except BaseException:  # noqa: BLE001 - the swallowing is the point of the test
        pass
    assert interrupt.interrupt_requested()
    with pytest.raises(KeyboardInterrupt):
        interrupt.raise_if_interrupted()


def test_the_handler_raises_keyboard_interrupt_like_pythons():
    with pytest.raises(KeyboardInterrupt):
        interrupt.note_interrupt(signal.SIGINT, None)
