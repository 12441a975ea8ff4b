"""The motion app says what α does and what bounds it (issue 47.1)."""

from fxspace.studio._motion import alpha_help, status_text


def _status(bound):
    return {"setup": "mood_walk", "frame": 3, "t_lower": 1.0, "t_upper": 0.9, "alpha": 0.0,
            "joy": 1.0, "hand": None, "turn": 0.0, "recording": False,
            "max_clock_rate": bound, "message": ""}  # fmt: skip


def test_status_line_names_the_bound():
    text = status_text(_status(1.0))
    assert "α: 1 keeps the lower body's tempo, 0 gives it the upper body's" in text
    assert "fastest captured example at that phase" in text
    assert "no joint steps farther in a frame than in any captured clip" in text
    assert "as printed" in status_text(_status(float("inf")))
    assert "× 0.9" in alpha_help(0.9)
