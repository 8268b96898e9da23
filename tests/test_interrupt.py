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


def test_after_the_outputs_are_in_place_ctrl_c_is_ignored_and_forgotten():
    previous = signal.signal(signal.SIGINT, interrupt.note_interrupt)
    try:
        try:
            interrupt.note_interrupt(signal.SIGINT, None)  # one that came after the last check
        except KeyboardInterrupt:
            pass
        interrupt.outputs_in_place()
        signal.raise_signal(signal.SIGINT)  # ignored: no KeyboardInterrupt
        assert not interrupt.interrupt_requested()
        interrupt.raise_if_interrupted()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_held_back_interrupt_reaches_gtvos_handler_too():
    """gtvo.core.atomic.deferred_interrupts under the CLI's handler (note_interrupt), not only under
    Python's default: the SIGINT waits for the end of the block, then is an interrupt."""
    from gtvo.core.atomic import deferred_interrupts

    previous = signal.signal(signal.SIGINT, interrupt.note_interrupt)
    steps = []
    try:
        with pytest.raises(KeyboardInterrupt):
            with deferred_interrupts():
                signal.raise_signal(signal.SIGINT)
                steps.append("after the signal")
        assert steps == ["after the signal"] and interrupt.interrupt_requested()
        assert signal.getsignal(signal.SIGINT) is interrupt.note_interrupt
        caught = []
        signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))  # a user's own handler
        with deferred_interrupts():
            signal.raise_signal(signal.SIGINT)
            assert caught == []
        assert caught == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_finished_run_interrupted_while_it_prints_its_summary_has_succeeded(tmp_path, capsys, monkeypatch):
    """Ctrl-C (a real SIGINT, under the CLI's handler) once the outputs are in place, while the
    summary is printed: exit 0 and the whole summary, not 130."""
    import gtvo.commands.run as run_command
    from gtvo import cli
    from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti

    seq = write_sequence_kitti(make_synthetic_sequence(n_frames=4, width=160, height=120, seed=1), tmp_path / "seq")
    printed = run_command.print_report

    def print_report_interrupted(report):
        signal.raise_signal(signal.SIGINT)
        printed(report)

    monkeypatch.setattr(run_command, "print_report", print_report_interrupted)
    previous = signal.signal(signal.SIGINT, interrupt.note_interrupt)
    try:
        assert cli.main(["run", str(seq), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
        assert signal.getsignal(signal.SIGINT) is interrupt.note_interrupt  # put back when the command returns
    finally:
        signal.signal(signal.SIGINT, previous)
    out = capsys.readouterr().out
    assert "outputs in" in out and (tmp_path / "out" / "report.json").is_file()
