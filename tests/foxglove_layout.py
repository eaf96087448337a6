"""The Foxglove layout for the daemon's standard topics, built with the Foxglove SDK's layout
types (a dev dependency: the gateway only ships the JSON). Regenerate the committed file with

    python tests/foxglove_layout.py > config/foxglove-layout.json

test_foxglove_layout.py checks that the file is what this builds and that every plotted
path is a field the log's schemas declare.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import foxglove.layouts as fl  # noqa: E402

from furnace_model.log.schema import (  # noqa: E402
    AMBIENT,
    BURNERS,
    LOG,
    MODEL_PARAMETERS,
    PARAM_NAMES,
    THERMOCOUPLES,
)
from furnace_model.simulation.furnace import PAPER  # noqa: E402


def _plot(paths: list[tuple[str, str]], y_label: str, step: bool = False) -> fl.PlotPanel:
    return fl.PlotPanel(config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=value, label=label, enabled=True, show_line=True,
                             line_interpolation="step" if step else "linear",
                             timestamp_method="publishTime")
               for value, label in paths],
        show_legend=True, legend_display="top", y_axis_label=y_label, is_synced=True))


def layout() -> fl.Layout:
    temps = _plot([(f"{THERMOCOUPLES}.{s}", s) for s in PAPER.sensors]
                  + [(f"{AMBIENT}.t_air", "t_air")], "°C")
    burners = _plot([(f"{BURNERS}{{source==\"modbus\"}}.count_{z}", f"burners {z}")
                     for z in PAPER.zones], "burners firing", step=True)
    params = _plot([(f"{MODEL_PARAMETERS}.{p}", p) for p in PARAM_NAMES], "parameter",
                   step=True)
    rmse = _plot([(f"{MODEL_PARAMETERS}.rmse_c.{z}", f"RMSE {z}") for z in PAPER.zones], "°C",
                 step=True)
    log = fl.LogPanel(config=fl.LogConfig(topic_to_render=LOG, min_log_level=1,
                                          show_level=True, show_time=True, show_name=True,
                                          show_source_location=True))
    return fl.Layout(content=fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=temps),
        fl.SplitItem(proportion=1, content=burners),
        fl.SplitItem(proportion=2, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=1, content=params),
            fl.SplitItem(proportion=1, content=rmse),
            fl.SplitItem(proportion=1, content=log),
        ])),
    ]))


def layout_json() -> str:
    return json.dumps(json.loads(layout().to_json()), indent=2, ensure_ascii=False) + "\n"


if __name__ == "__main__":
    sys.stdout.write(layout_json())
