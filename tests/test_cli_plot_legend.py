"""`marlin-temp plot`: the legend never covers a curve, in the PNG (matplotlib, Agg) nor in the terminal (--show).

Inside the axes the legend sat on the bed's curve, which runs low and flat across the whole width, where the
corners are; it now stands outside the axes, to their right. The figure is the one `plot --output` saves, drawn
from a heat-up log written by the real `TemperatureLog`.
"""

from __future__ import annotations

import re
from datetime import datetime
from pathlib import Path

import pytest
from test_cli_plot import START, reading
from typer.testing import CliRunner

from marlin_temp.logs.files import TemperatureLog, read_log
from marlin_temp.logs.plot import plot_data, png_figure, terminal_plot
from marlin_temp.main import app

runner = CliRunner()


async def heat_up_log(path: Path) -> Path:
    """Two minutes of a hotend heating to 200 C and a bed to 60 C, a reading a second."""
    async with TemperatureLog(path, "csv", interval_s=1.0) as log:
        for second in range(120):
            hotend = min(25 + second * 3.0, 200.0)
            bed = min(25 + second * 0.4, 60.0)
            log.add(reading(f"T:{hotend:.2f} /200.00 B:{bed:.2f} /60.00 @:127 B@:127", float(second), START))
    return path


async def test_the_png_legend_stands_outside_the_axes(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="matplotlib is optional (pip install 'marlin-aio[plot]')")
    import matplotlib.pyplot as plt

    path = await heat_up_log(tmp_path / "heat.csv")
    figure = png_figure(plot_data(read_log(path), path), path)
    try:
        figure.canvas.draw()
        renderer = figure.canvas.get_renderer()  # Agg's canvas has one
        axes = figure.axes[0]
        legend = axes.get_legend()
        assert legend is not None
        assert [text.get_text() for text in legend.get_texts()] == [
            "hotend actual",
            "hotend target",
            "bed actual",
            "bed target",
        ]
        box, data_area = legend.get_window_extent(renderer), axes.get_window_extent(renderer)
        assert not box.overlaps(data_area), (box, data_area)
        # Nor does it cover a point of the bed's curve, nor leave the figure.
        bed = next(line for line in axes.get_lines() if line.get_label() == "bed actual")
        points = axes.transData.transform(bed.get_xydata())
        assert not any(box.contains(x, y) for x, y in points)
        assert figure.bbox.contains(box.x0, box.y0) and figure.bbox.contains(box.x1, box.y1), (box, figure.bbox)
        # The time axis is labelled with the clock times of the log.
        labels = [label.get_text() for label in axes.get_xticklabels() if label.get_text()]
        assert labels and all(re.fullmatch(r"\d\d:\d\d:\d\d", label) for label in labels), labels
        start = f"{datetime.fromtimestamp(START):%H:%M}"
        assert any(label.startswith(start) for label in labels), labels
    finally:
        plt.close(figure)


async def test_the_png_is_written(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="matplotlib is optional (pip install 'marlin-aio[plot]')")
    path = await heat_up_log(tmp_path / "heat.csv")
    png = tmp_path / "heat.png"
    result = runner.invoke(app, ["plot", str(path), "--output", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("width", [120, 80, 40])
async def test_the_terminal_legend_is_a_line_of_its_own_under_the_time_axis(tmp_path: Path, width: int) -> None:
    path = await heat_up_log(tmp_path / "heat.csv")
    lines = terminal_plot(plot_data(read_log(path), path), width=width, height=16).plain.splitlines()
    axis = next(number for number, line in enumerate(lines) if re.search(r"\d\d:\d\d:\d\d\s*$", line))
    legend = " ".join(lines[axis + 1 :])
    assert "• hotend" in legend and "• bed" in legend and "─ target" in legend
    # The chart's rows above the axis hold only the curves: no legend text drawn over them.
    assert not any("hotend" in line or "bed" in line for line in lines[:axis])
    assert sum("•" in line for line in lines[:axis]) >= 4  # the curves are there
