"""``rigslim lod``'s per-level lines (:mod:`rigslim.commands.lod_levels`)."""

from __future__ import annotations

from rigslim.commands.lod_levels import print_levels


def _row(label, faces, error_max, coverage, distance):
    return {"label": label, "faces": faces, "joints": 2, "influences": 3 * faces, "error_max_m": error_max,
            "error_rms_m": error_max / 10, "screen_coverage": coverage, "switch_distance_m": distance}


def test_a_level_the_coarser_one_hides_says_it_is_never_shown(capsys):
    """A finer level whose coarser neighbour switches in at the same coverage (its max error no larger: the
    minigun's 549- and 319-face levels, 0.174 and 0.172 m) is never displayed, and its line says why; levels
    with their own coverage range do not."""
    print_levels([_row("quartic-50pct", 549, 0.174, 0.000282, 165.0),
                  _row("quartic-25pct-319f", 319, 0.172, 0.000282, 165.0)])
    first, second = capsys.readouterr().out.splitlines()
    assert first.endswith("; never shown: quartic-25pct-319f's max error (0.172 m) is no larger, so it switches "
                          "in at the same distance")
    assert "never shown" not in second
    print_levels([_row("quartic-50pct", 549, 0.05, 0.001, 40.0), _row("quartic-25pct", 275, 0.2, 0.0002, 160.0)])
    assert "never shown" not in capsys.readouterr().out
