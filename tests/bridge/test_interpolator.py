"""Interpolator: closed-form profiles, the section X reference, move text and files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bridge.errors import MoveError, MoveFileError
from bridge.interpolator import Interpolator, Move, Table, load_move_file, parse_move
from plant_sim.paper.scenarios import SectionX
from virtual_bus.formats.axis import load_axis

CYCLE = 0.001


def play(interp: Interpolator, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    pos, spd = np.empty(cycles), np.empty(cycles)
    for k in range(cycles):
        interp.step()
        pos[k], spd[k] = interp.position, interp.speed
    return pos, spd


def test_speed_step_move_equals_the_section_x_reference() -> None:
    axis = load_axis("config/paper_axis.toml")
    refs = SectionX(end_s=1.5, stop_s=1.0).references(axis)
    interp = Interpolator(CYCLE)
    interp.queue(Move(target=SectionX.feed * 1.0, feed=SectionX.feed))
    pos, spd = play(interp, refs.position.size)
    np.testing.assert_allclose(pos, refs.position, atol=1e-15)
    np.testing.assert_allclose(spd, refs.speed, atol=1e-12)


@pytest.mark.parametrize(("target", "feed", "accel"), [(0.1, 0.05, 0.5), (-0.02, 0.05, 0.5)])
def test_trapezoid_reaches_target_with_bounded_speed_and_acceleration(
    target: float, feed: float, accel: float
) -> None:
    interp = Interpolator(CYCLE, position=0.01)
    interp.queue(Move(target=target, feed=feed, accel=accel))
    pos, spd = play(interp, 3000)
    assert pos[-1] == target and spd[-1] == 0.0 and not interp.busy
    # forward difference: x[k+1] = x[k] + v[k] T exactly
    np.testing.assert_allclose(pos[1:], pos[:-1] + spd[:-1] * CYCLE, atol=1e-15)
    assert np.max(np.abs(spd)) <= feed * (1 + 1e-9)
    assert np.max(np.abs(np.diff(spd))) / CYCLE <= accel * 1.01
    # duration: distance/feed + feed/accel for a trapezoid (analytic)
    dist = abs(target - 0.01)
    moving = np.count_nonzero(spd) * CYCLE
    assert moving == pytest.approx(dist / feed + feed / accel, abs=2 * CYCLE)


def test_short_move_is_triangular() -> None:
    interp = Interpolator(CYCLE)
    interp.queue(Move(target=0.001, feed=0.05, accel=0.5))  # sqrt(a d) = 0.0224 < feed
    _, spd = play(interp, 200)
    assert np.max(spd) == pytest.approx(math.sqrt(0.5 * 0.001), rel=0.02)


def test_moves_chain_and_dwell_holds() -> None:
    interp = Interpolator(CYCLE)
    interp.queue(Move(0.01, 0.05, dwell_s=0.1))
    interp.queue(Move(0.0, 0.05))
    pos, _ = play(interp, 600)
    arrive = int(np.argmax(pos == 0.01))
    assert np.all(pos[arrive : arrive + 100] == 0.01)
    assert pos[-1] == 0.0 and not interp.busy


def test_table_plays_then_holds_its_last_position() -> None:
    interp = Interpolator(CYCLE)
    interp.queue(Table(np.array([0.0, 0.1, 0.2]), np.array([100.0, 100.0, 0.0])))
    pos, spd = play(interp, 5)
    assert list(pos) == [0.0, 0.1, 0.2, 0.2, 0.2]
    assert list(spd) == [100.0, 100.0, 0.0, 0.0, 0.0]


def test_hold_drops_everything() -> None:
    interp = Interpolator(CYCLE)
    interp.queue(Move(1.0, 0.05))
    play(interp, 10)
    interp.hold(0.123)
    pos, spd = play(interp, 3)
    assert np.all(pos == 0.123) and np.all(spd == 0.0) and not interp.busy


def test_parse_move() -> None:
    assert parse_move("target=0.3,feed=0.05") == Move(0.3, 0.05)
    assert parse_move("target=-1, feed=2, accel=3, dwell=0.5") == Move(-1.0, 2.0, 3.0, 0.5)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("0.3,0.05", "key=value"),
        ("target=0.3", "missing 'feed'"),
        ("target=x,feed=1", "not a number"),
        ("target=1,feed=0", "feed = 0.0"),
        ("target=1,feed=1,speed=2", "unknown key"),
        ("target=nan,feed=1", "finite"),
    ],
)
def test_parse_move_errors_name_the_problem(text: str, fragment: str) -> None:
    with pytest.raises(MoveError, match=fragment):
        parse_move(text)


def test_move_file(tmp_path: Path) -> None:
    path = tmp_path / "moves.toml"
    path.write_text(
        "[[move]]\ntarget = 0.2\nfeed = 0.05\naccel = 1.0\n\n[[move]]\ntarget = 0\nfeed = 0.1\n"
    )
    assert load_move_file(path) == [Move(0.2, 0.05, 1.0), Move(0.0, 0.1)]


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ("", "no \\[\\[move\\]\\]"),
        ("[[move]]\ntarget = 1\n", "move 1: missing 'feed'"),
        ("[[move]]\ntarget = 1\nfeed = 1\n[[move]]\ntarget = 1\nfeed = -1\n", "move 2"),
        ("speed = 3\n", "unknown key"),
        ("[[move]\n", "not valid TOML"),
    ],
)
def test_move_file_errors(tmp_path: Path, body: str, fragment: str) -> None:
    path = tmp_path / "moves.toml"
    path.write_text(body)
    with pytest.raises(MoveFileError, match=fragment):
        load_move_file(path)


def test_missing_move_file(tmp_path: Path) -> None:
    with pytest.raises(MoveFileError, match="no such move file"):
        load_move_file(tmp_path / "nope.toml")
