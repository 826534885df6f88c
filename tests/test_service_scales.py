"""The daemon's reports of the learnt scales (service/scales.py): SOURCE fields and what
the journal gets, driven by a real ScaleLearner's warning text and a clock of the test's."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from mousedom.fusion.scalelearn import ScaleLearner
from mousedom.service import scales
from mousedom.service.scales import ScaleLog, scale_fields, warning_texts

NAMES = ("front", "left", "right")


def _learner(g: list[float], spread: list[float], applied: list[float] | None = None):
    """A real ScaleLearner of a triangle rig, its estimates set as a renewal leaves them."""
    pos = np.array([[0.15, 0.0], [-0.075, 0.13], [-0.075, -0.13]])
    eye = np.repeat(np.eye(2)[None], 3, axis=0) * (0.0254 / 450)
    lrn = ScaleLearner("lsq", eye, pos, np.full(3, 0.3), 0.01, 0.1)
    lrn.estimate = np.repeat(np.array(g, float)[:, None], 2, axis=1)
    lrn.spread = np.repeat(np.array(spread, float)[:, None], 2, axis=1)
    lrn.scale = np.repeat(np.array(applied or [1.0] * 3, float)[:, None], 2, axis=1)
    lrn.version += 1
    return lrn


def _renew(lrn, g, spread) -> None:
    lrn.estimate = np.repeat(np.array(g, float)[:, None], 2, axis=1)
    lrn.spread = np.repeat(np.array(spread, float)[:, None], 2, axis=1)
    lrn.version += 1


def test_source_fields_one_number_per_mouse_null_where_nothing_is_learnt():
    lrn = _learner([1.0, 0.88, 1.004], [0.0003, 0.002, np.inf], applied=[1.0, 0.9, 1.0])
    f = scale_fields(lrn, NAMES, applying=True)
    assert f[0] == {"scale": 1.0, "scale_spread": 0.0003, "scale_applied": False,
                    "scale_warning": None}  # fmt: skip
    assert f[1]["scale"] == 0.88 and f[1]["scale_applied"] is True
    assert f[1]["scale_warning"].startswith("mouse left reads 14 % more than the others")
    # no spread yet (too little motion of it): no number claimed
    assert f[2] == {"scale": None, "scale_spread": None, "scale_applied": False,
                    "scale_warning": None}  # fmt: skip
    # robust.learn_scale off: estimated and reported, never applied
    assert scale_fields(lrn, NAMES, applying=False)[1]["scale_applied"] is False
    # two mice, or fault handling off: the keys are there, null
    assert (
        scale_fields(None, ("a", "b"), True)
        == [{"scale": None, "scale_spread": None, "scale_applied": False, "scale_warning": None}]
        * 2
    )


def test_warnings_are_told_to_their_mouse_whatever_the_names():
    """The learner's lines name the mouse; names that hold each other or the words of the
    line are told apart."""
    names = ("mouse", "mouse 1", "reads")
    lrn = _learner([1.0, 1.2, 0.8], [0.001] * 3)
    texts = warning_texts(lrn, names)
    assert set(texts) == {"mouse 1", "reads"}
    assert texts["mouse 1"].startswith("mouse mouse 1 reads 17 % less than the others")
    assert texts["reads"].startswith("mouse reads reads 25 % more")


def test_the_journal_gets_a_warning_once_not_at_every_renewal(caplog):
    """Logged when a mouse's warning appears; at the renewals after (twice a second) not
    again, until REPEAT_S has passed; over once it has been absent CLEAR_S, said once;
    a mouse hovering at the threshold (in and out at alternate renewals) is not logged
    in and out."""
    caplog.set_level(logging.INFO, logger="mousedom.service.scales")
    log = ScaleLog()
    lrn = _learner([1.0, 1.0, 1.0], [0.001] * 3)
    t = 100.0

    def step(g, n=1, dt=0.5):
        nonlocal t
        for _ in range(n):
            _renew(lrn, g, [0.001] * 3)
            assert log.due(lrn)
            log.renewed(lrn, NAMES, t)
            assert not log.due(lrn)  # read: nothing new until the next renewal
            t += dt

    def lines():
        return [(r.levelname, r.getMessage()) for r in caplog.records]

    step([1.0, 1.0, 1.0], 4)
    assert lines() == []
    step([1.0, 0.85, 1.0], 40)  # 20 s of renewals with the warning
    assert lines() == [("WARNING", "mouse left reads 18 % more than the others: check its "
                        "cpi (learnt scale 0.850 +- 0.001)")]  # fmt: skip
    # hovering at the threshold: in, out, in... for a minute: nothing new
    for _ in range(60):
        step([1.0, 0.899, 1.0])
        step([1.0, 0.901, 1.0])
    assert len(lines()) == 1
    # persisting past REPEAT_S since it was logged: said again, with how long
    step([1.0, 0.85, 1.0], 1, dt=scales.REPEAT_S)
    step([1.0, 0.85, 1.0], 1)
    assert len(lines()) == 2 and lines()[1][0] == "WARNING"
    assert lines()[1][1].endswith("(still so, for 11 minutes)"), lines()[1]
    # the config corrected: after CLEAR_S without the warning, over, said once
    step([1.0, 1.002, 1.0], int(scales.CLEAR_S / 0.5) + 10)
    assert lines()[2:] == [
        ("INFO", "mouse left agrees with the others again (learnt scale 1.002 +- 0.001)")
    ]
    # a second mouse, then a reload that drops a warned mouse's name: nothing about it
    step([1.0, 1.0, 1.3], 2)
    assert len(lines()) == 4 and "mouse right reads 23 % less" in lines()[3][1]
    lrn2 = _learner([1.0, 1.0], [0.001] * 2)
    assert log.due(lrn2)  # another learner (a reload): read even at an equal version
    log.renewed(lrn2, ("front", "left"), t + 30)
    assert len(lines()) == 4 and log.warned == {}


def test_a_new_learner_is_read_even_at_the_version_last_read():
    log = ScaleLog()
    a = _learner([1.0] * 3, [0.001] * 3)
    log.renewed(a, NAMES, 0.0)
    b = _learner([1.0] * 3, [0.001] * 3)
    assert a.version == b.version and log.due(b) and not log.due(a) and not log.due(None)


@pytest.mark.parametrize("spread", [0.03, 0.05])
def test_a_scale_within_its_uncertainty_is_not_warned_of(spread):
    """The learner's own rule: 10 % off, beyond three of its standard deviations."""
    lrn = _learner([1.0, 0.88, 1.0], [0.001, spread, 0.001])
    assert bool(warning_texts(lrn, NAMES)) is (0.12 > 3 * spread)


def test_a_change_of_scale_is_logged_once(caplog):
    """A mouse whose scale changed during the drive (scalelearn's change of scale: another
    floor, a lens) is said once (INFO), at the renewal that found it, not at the next."""
    caplog.set_level(logging.INFO, logger="mousedom.service.scales")
    log = ScaleLog()
    lrn = _learner([1.0] * 3, [0.001] * 3)
    log.renewed(lrn, NAMES, 0.0)
    lrn.changes, lrn.changed = 1, [(2, 1.08)]
    _renew(lrn, [1.0, 1.0, 1.08], [0.001] * 3)
    log.renewed(lrn, NAMES, 0.5)
    _renew(lrn, [1.0, 1.0, 1.08], [0.001] * 3)
    log.renewed(lrn, NAMES, 1.0)
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        ("INFO", "mouse right reads 7.4 % less than it did (another floor, its lens?): the "
         "scales are learnt again from the change on")
    ]  # fmt: skip
