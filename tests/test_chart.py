"""The terminal chart both `watch` and `plot --show` draw (`common.chart.time_chart`), on curves made by hand."""

from __future__ import annotations

from rich.console import Console
from rich.text import Text

from marlin_temp.common.chart import Curve, heater_colour, legend, time_chart


def rendered(text: Text, width: int = 80) -> list[str]:
    console = Console(record=True, width=width)
    console.print(text)
    return console.export_text().splitlines()


def plot_rows(lines: list[str]) -> list[str]:
    """The grid's rows, without the temperature axis."""
    return [line[6:] for line in lines if line[5:6] in ("┤", "│")]


def test_each_column_shows_the_last_reading_in_it_and_a_gap_stays_empty() -> None:
    # Readings for the first and last ten seconds of a minute: nothing in between.
    points = [(float(t), 100.0, 200.0) for t in [*range(10), *range(50, 61)]]
    lines = rendered(time_chart([Curve("hotend", points)], 0.0, 60.0, width=80, height=9, time_labels=("a", "b")))
    rows = plot_rows(lines)
    assert len(rows) == 9
    dots = next(row for row in rows if "•" in row)
    assert dots.strip(" •") == ""  # one row of dots, for 100 C
    assert "   " * 10 in dots.strip()  # the gap
    assert any("─" in row for row in rows)  # the target line
    assert lines[9].startswith("      a") and lines[9].rstrip().endswith("b")  # the time axis
    assert lines[-1].split() == ["•", "hotend", "─", "target"]


def test_the_temperature_axis_is_labelled_with_round_quarters() -> None:
    lines = rendered(
        time_chart([Curve("bed", [(0.0, 60.0, 60.0)])], 0.0, 1.0, width=60, height=9, time_labels=("", ""))
    )
    labels = [line[:5].strip() for line in lines if line[5:6] == "┤"]
    assert labels == ["100", "75", "50", "25", "0"]  # 60 C: a top of 100


def test_marks_stand_under_their_times_and_never_touch() -> None:
    marks = [(0.0, "1"), (50.0, "2"), (50.5, "3"), (100.0, "4")]
    chart = time_chart([Curve("hotend", [(0.0, 20.0, None)])], 0.0, 100.0, width=60, height=4, time_labels=("", ""))
    with_marks = time_chart(
        [Curve("hotend", [(0.0, 20.0, None)])], 0.0, 100.0, width=60, height=4, time_labels=("", ""), marks=marks
    )
    lines = rendered(with_marks, 60)
    assert len(lines) == len(rendered(chart, 60)) + 1
    row = lines[5]
    assert row.split() == ["1", "2", "4"]  # 3 would touch 2: left out
    assert row.index("1") == 6 and row.index("4") == 6 + 52  # the first and the last column


def test_the_legend_breaks_between_heaters_on_a_narrow_terminal() -> None:
    curves = [Curve(f"hotend {number}", []) for number in range(6)]
    lines = rendered(legend(curves, 40), 40)
    assert len(lines) > 1
    assert all(line.startswith("      •") for line in lines[:-1])
    assert all(len(line) <= 40 for line in lines)
    assert " ".join(" ".join(lines).split()).startswith("• hotend 0 • hotend 1")


def test_each_heater_keeps_its_colour_in_every_view() -> None:
    assert heater_colour("hotend") == heater_colour("hotend 0") == "red"
    assert heater_colour("hotend 1") == "yellow"
    assert (heater_colour("bed"), heater_colour("chamber"), heater_colour("probe")) == ("blue", "green", "magenta")
