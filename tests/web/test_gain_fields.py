"""The web panel's gain text fields refuse non-finite, out-of-range and wrongly shaped values, naming the gain."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from app.controller.gains import ControllerGains
from app.web.controls import SIX_GAINS, Controls, format_six


class Actions:
    """The demo application, reduced to its gains."""

    def __init__(self) -> None:
        self.gains = ControllerGains()
        self.applied: list[ControllerGains] = []

    def set_gains(self, gains: ControllerGains) -> None:
        self.applied.append(gains)


def panel(**texts: str) -> SimpleNamespace:
    """What :meth:`Controls._apply_gains` reads of the panel, with some gain fields typed over."""
    gains = ControllerGains()
    six = {name: SimpleNamespace(value=texts.get(name, format_six(getattr(gains, name)))) for name, _, _ in SIX_GAINS}
    shown: list[ControllerGains] = []
    return SimpleNamespace(
        actions=Actions(),
        shown=shown,
        show_gains=shown.append,
        _quiet=lambda: False,
        six=six,
        mode=SimpleNamespace(value=gains.mode),
        rtc=SimpleNamespace(value=gains.rtc),
        remove_payload=SimpleNamespace(value=gains.remove_payload),
        gravity_compensation=SimpleNamespace(value=gains.gravity_compensation),
        gain_message=SimpleNamespace(content=""),
    )


def apply(p: SimpleNamespace) -> str:
    Controls._apply_gains(p, SimpleNamespace(client=None))
    return str(p.gain_message.content)


@pytest.mark.parametrize("name", [name for name, _, _ in SIX_GAINS])
@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("inf, 1, 1, 1, 1, 1", "finite"),
        ("1e400, 1, 1, 1, 1, 1", "finite"),
        ("1e30, 1, 1, 1, 1, 1", "must be"),
        ("nan, 1, 1, 1, 1, 1", "NaN"),
        ("-1, 1, 1, 1, 1, 1", "non-negative"),
        ("1, 1, 1", "expected 6 values"),
        ("1, 2, x, 4, 5, 6", "not six comma-separated numbers"),
    ],
)
def test_a_bad_gain_is_refused_naming_it(name: str, text: str, reason: str) -> None:
    p = panel(**{name: text})
    message = apply(p)
    assert message.startswith(f"**Refused {name}: ")
    assert reason in message
    assert "kept the previous gains" in message
    assert p.actions.applied == []
    assert p.shown == [p.actions.gains]  # the fields are given the gains in force again


def test_good_gains_are_applied() -> None:
    p = panel(k_t="0.5, 0.5, 0.5, 0.2, 0.2, 0.2")
    assert apply(p) == "gains applied"
    assert p.shown == []
    assert p.actions.applied[0].k_t == (0.5, 0.5, 0.5, 0.2, 0.2, 0.2)


@pytest.mark.parametrize(("name", "text"), [("mode", "nonsense"), ("rtc", ""), ("rtc", "../hooke")])
def test_a_choice_the_dropdown_does_not_offer_is_refused_naming_it(name: str, text: str) -> None:
    """A client speaking viser's protocol can send any text for a dropdown (viser checks none): the
    gains hold ``Literal`` fields to their choices on construction (harden8). Before, such an
    ``rtc`` was applied and ended the servo loop's process (``RTC_LAWS.index``)."""
    p = panel()
    setattr(p, name, SimpleNamespace(value=text))
    message = apply(p)
    assert message.startswith(f"**Refused {name}: must be one of ")
    assert f"got {text!r}" in message
    assert p.actions.applied == []
