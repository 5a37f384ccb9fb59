"""interrupt_on_signals / signals_interrupt / interrupts_deferred: a stop signal becomes a KeyboardInterrupt, at once
or at the end of a block that must not be cut (the simulator's step, where Panda3D's task manager would print it as a
traceback)."""

import os
import signal

import pytest
from msfsu_common.processes import interrupts_deferred, signals_interrupt


@pytest.fixture
def stop_signals_interrupt():
    with signals_interrupt():
        yield


def stop(sig: signal.Signals = signal.SIGTERM) -> None:
    os.kill(os.getpid(), sig)  # the handler runs in this (the main) thread before the next statement


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_outside_a_block_interrupts_at_once(stop_signals_interrupt, sig):
    ran = []
    with pytest.raises(KeyboardInterrupt):
        stop(sig)
        ran.append("after")
    assert ran == []


def test_a_stop_signal_inside_a_block_interrupts_at_its_end(stop_signals_interrupt):
    ran = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            stop()
            ran.append("rest of the block")
        ran.append("after the block")
    assert ran == ["rest of the block"]
    stop_nothing_pending()


def test_nested_blocks_interrupt_at_the_outermost_end(stop_signals_interrupt):
    ran = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            with interrupts_deferred():
                stop()
            ran.append("outer block goes on")
    assert ran == ["outer block goes on"]
    stop_nothing_pending()


def test_a_block_ending_in_its_own_keyboard_interrupt_raises_it_once(stop_signals_interrupt):
    """Panda3D defers a Ctrl-C to the end of its task loop's step and raises it there: the same stop, not two."""
    with pytest.raises(KeyboardInterrupt, match="the block's own"):
        with interrupts_deferred():
            stop()
            raise KeyboardInterrupt("the block's own")
    stop_nothing_pending()


def test_a_block_ending_in_another_error_keeps_the_interrupt_for_the_next_block(stop_signals_interrupt):
    with pytest.raises(RuntimeError):
        with interrupts_deferred():
            stop()
            raise RuntimeError("the block failed")
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            pass
    stop_nothing_pending()


def test_without_a_signal_a_block_returns_normally(stop_signals_interrupt):
    @interrupts_deferred()
    def step(value: int) -> int:
        return value + 1

    assert step(1) == 2 and step(2) == 3


def stop_nothing_pending() -> None:
    with interrupts_deferred():
        pass  # would raise if an interrupt were still held


def test_signals_interrupt_puts_the_handlers_from_before_back():
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    with pytest.raises(KeyboardInterrupt):
        with signals_interrupt():
            assert all(signal.getsignal(sig) is not handler for sig, handler in before.items())
            stop()
    assert {sig: signal.getsignal(sig) for sig in before} == before
