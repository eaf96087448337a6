"""Malformed heat-up tables and MCAP logs, built from a good file of each kind: what a
plant's disks, spreadsheets and half-copied USB sticks hand to the commands."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
from daq_processes import SCENARIO

from furnace_daq.mcaplog import LogWriter
from furnace_model.experiment import write_table
from furnace_model.log.schema import AMBIENT, BURNERS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

T0 = 1_772_431_200 * 10**9  # 2026-03-02T06:00:00Z
RANDOM = np.random.default_rng(7).integers(0, 256, 4096, dtype=np.uint8).tobytes()


def good_frame(minutes: int = 90) -> pd.DataFrame:
    """A clean heat-up in the tabular contract (the noise-free acquisition scenario)."""
    sc = load_scenario(SCENARIO)
    t = np.arange(minutes, dtype=float)
    run = Plant.from_scenario(sc).run(sc.inputs(), t, sc.initial_c)
    frame = pd.DataFrame({"timestamp": pd.date_range("2026-03-02T06:00:00Z", periods=minutes,
                                                     freq="min").strftime("%Y-%m-%dT%H:%M:%SZ")})
    for i, s in enumerate(PAPER.sensors):
        frame[f"tc_{s}"] = np.round(run.tc[:, i], 1)
    for i, z in enumerate(PAPER.zones):
        frame[f"burners_{z}"] = [sc.burners_at(x)[i] for x in t]
    frame["t_air"] = sc.t_air_c
    return frame


def _csv_text(frame: pd.DataFrame) -> str:
    return frame.to_csv(index=False)


def table_cases(d: Path) -> dict[str, Path]:
    """name -> a bad CSV or Parquet file."""
    good = good_frame()
    text = _csv_text(good)
    cases: dict[str, bytes | str | pd.DataFrame] = {}
    cases["empty.csv"] = b""
    cases["header_only.csv"] = text.splitlines()[0] + "\n"
    cases["random.csv"] = RANDOM
    cases["non_utf8.csv"] = text.replace("tc_soak_1", "tc_soak_\xb01").encode("latin-1")
    cases["non_utf8_cell.csv"] = text.replace(",25.0\n", ",2\xb05\n", 1).encode("latin-1")
    cases["truncated.csv"] = text[: len(text) // 2 + 7]
    cases["no_time.csv"] = good.drop(columns="timestamp")
    cases["both_times.csv"] = good.assign(t_min=np.arange(len(good), dtype=float))
    cases["no_burners.csv"] = good.drop(columns="burners_heat")
    cases["no_tc_of_a_zone.csv"] = good.drop(columns=["tc_heat_1", "tc_heat_2"])
    cases["wrong_columns.csv"] = "a;b;c\n1;2;3\n"
    cases["text_in_numbers.csv"] = good.astype({"tc_soak_1": object}).assign(
        tc_soak_1=lambda f: f["tc_soak_1"].where(f.index != 5, "hot"))
    cases["nan_burners.csv"] = good.assign(burners_soak=lambda f: f["burners_soak"]
                                           .astype(float).where(f.index != 3, np.nan))
    cases["inf_tc.csv"] = text.replace(",25.0\n", ",inf\n", 3).replace(
        text.splitlines()[4].split(",")[1], "inf", 1)
    cases["nan_everywhere.csv"] = good.assign(**{f"tc_{s}": np.nan for s in PAPER.sensors})
    cases["huge.csv"] = good.assign(tc_soak_1=1e308, t_air=1e300)
    cases["overflow.csv"] = text.replace(text.splitlines()[3].split(",")[1], "1e400", 1)
    cases["huge_burners.csv"] = good.assign(burners_soak=10**30)
    cases["negative_burners.csv"] = good.assign(burners_heat=-1)
    cases["fractional_burners.csv"] = good.assign(burners_heat=2.5)
    cases["duplicated_times.csv"] = pd.concat([good, good.iloc[[10]]]).sort_index()
    cases["unsorted_times.csv"] = good.iloc[::-1]
    cases["naive_times.csv"] = good.assign(timestamp=good["timestamp"].str.rstrip("Z"))
    cases["bad_times.csv"] = good.assign(timestamp="yesterday")
    cases["one_row.csv"] = good.iloc[:1]
    cases["t_min_nan.csv"] = good.drop(columns="timestamp").assign(
        t_min=np.where(np.arange(len(good)) == 4, np.nan, np.arange(len(good), dtype=float)))
    cases["nul_bytes.csv"] = text.encode().replace(b"\n", b"\x00\n", 5)
    cases["random.parquet"] = RANDOM
    cases["empty.parquet"] = b""
    cases["csv_named.parquet"] = text
    cases["no_rows.parquet"] = good.iloc[:0]
    cases["wrong_types.parquet"] = good.astype(str)
    cases["wrong_columns.parquet"] = pd.DataFrame({"x": [1, 2], "y": ["a", "b"]})
    cases["nested.parquet"] = good.assign(tc_soak_1=[[1.0, 2.0]] * len(good))
    cases["inf.parquet"] = good.assign(tc_heat_1=np.inf, t_air=-np.inf)
    cases["duplicated_times.parquet"] = pd.concat([good, good.iloc[[10]]]).sort_index()
    paths = {}
    for name, content in cases.items():
        path = d / name
        if isinstance(content, pd.DataFrame):
            if name.endswith(".parquet"):
                content.to_parquet(path, index=False)
            else:
                content.to_csv(path, index=False)
        elif isinstance(content, str):
            path.write_text(content)
        else:
            path.write_bytes(content)
        paths[name] = path
    good_parquet = d / "good.parquet"
    write_table(good, good_parquet)
    data = good_parquet.read_bytes()
    (d / "truncated.parquet").write_bytes(data[: len(data) // 2])
    paths["truncated.parquet"] = d / "truncated.parquet"
    return paths


def _log(d: Path, name: str, put: Callable[[LogWriter], None]) -> Path:
    w = LogWriter(d / f"w-{name}", flush_interval_s=0.0)
    put(w)
    w.close()
    (f,) = (d / f"w-{name}").glob("*.mcap")
    return f.rename(d / name)


def _tc(i: int, **over) -> dict:
    m: dict = {s: 400.0 + i for s in PAPER.sensors}
    m["quality"] = {s: "ok" for s in PAPER.sensors}
    m["plc_seconds"] = float(60 * i)
    m.update(over)
    return m


def _burn(**over) -> dict:
    m: dict = {"soak": [True] * 2 + [False] * 8, "heat": [False] * 8, "preheat": [False] * 8,
               "count_soak": 2, "count_heat": 0, "count_preheat": 0, "source": "modbus",
               "quality": "ok"}
    m.update(over)
    return m


def _series(w: LogWriter, n: int = 30, tc: Callable[[int], dict] = _tc,
            burn: Callable[[int], dict] = lambda i: _burn(), step_ns: int = 60 * 10**9) -> None:
    for i in range(n):
        t = T0 + i * step_ns
        w.write(THERMOCOUPLES, tc(i), t)
        w.write(BURNERS, burn(i), t)
        w.write(AMBIENT, {"t_air": 25.0, "quality": "ok"}, t)
        w.maybe_flush(float(i))


def mcap_cases(d: Path) -> dict[str, Path]:
    """name -> a bad MCAP log (every one with the .mcap suffix the commands expect)."""
    d.mkdir(exist_ok=True)
    good = _log(d, "good.mcap", _series)
    data = good.read_bytes()
    raw = {
        "empty.mcap": b"",
        "random.mcap": RANDOM,
        "magic_then_random.mcap": data[:8] + RANDOM,
        "cut_in_header.mcap": data[:14],
        "cut_in_first_chunk.mcap": data[: min(len(data) - 30, 200)],
        "zeros_after_header.mcap": data[:60] + bytes(4096),
        "text.mcap": b"timestamp,tc_soak_1\n2026-03-02T06:00:00Z,400\n",
        "csv_as_log.mcap": _csv_text(good_frame()).encode(),
    }
    for name, content in raw.items():
        (d / name).write_bytes(content)
    paths = {name: d / name for name in raw}
    paths["not_json.mcap"] = _log(d, "not_json.mcap", lambda w: (
        _series(w, 3), _raw_message(w, b"\xff\xfe{")))
    paths["json_array.mcap"] = _log(d, "json_array.mcap", lambda w: (
        _series(w, 3), _raw_message(w, b"[1, 2, 3]")))
    paths["nan_token.mcap"] = _log(d, "nan_token.mcap", lambda w: (
        _series(w, 3), _raw_message(w, b'{"soak_1": NaN, "quality": {"soak_1": "ok"}}')))
    paths["wrong_field_types.mcap"] = _log(d, "wrong_field_types.mcap", lambda w: _series(
        w, 10, tc=lambda i: _tc(i, soak_1="hot", heat_1=[1, 2], quality="fine")))
    paths["missing_fields.mcap"] = _log(d, "missing_fields.mcap", lambda w: _series(
        w, 10, tc=lambda i: {"plc_seconds": 60.0 * i}, burn=lambda i: {"source": "modbus"}))
    paths["huge_values.mcap"] = _log(d, "huge_values.mcap", lambda w: _series(
        w, 10, tc=lambda i: _tc(i, soak_1=1e308, heat_1=-1e308, plc_seconds=1e300),
        burn=lambda i: _burn(count_soak=10**40, soak=[True] * 1000)))
    paths["duplicated_times.mcap"] = _log(d, "duplicated_times.mcap", lambda w: _series(
        w, 10, step_ns=0))
    paths["burners_only.mcap"] = _log(d, "burners_only.mcap", lambda w: [
        w.write(BURNERS, _burn(), T0 + i * 10**9) for i in range(5)])
    paths["status_only.mcap"] = _log(d, "status_only.mcap", lambda w: [
        w.write(DAQ_STATUS, {"state": "disconnected", "detail": "x"}, T0 + i * 10**9)
        for i in range(5)])
    paths["wrong_schema_encoding.mcap"] = _foreign_log(d / "wrong_schema_encoding.mcap")
    return paths


def _raw_message(w: LogWriter, data: bytes) -> None:
    """A message whose bytes are not what the writer would make of a dict."""
    w.write(THERMOCOUPLES, _tc(0), T0 + 10**12)  # the file and channel exist
    f = w._file
    f.writer.add_message(f.channels[THERMOCOUPLES], T0 + 10**12 + 1, data, T0 + 10**12 + 1)


def _foreign_log(path: Path) -> Path:
    """A valid MCAP file another program wrote: protobuf-encoded channels on our topics."""
    from mcap.writer import Writer
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="other")
        sid = w.register_schema("foo.Bar", "protobuf", b"\x0a\x03abc")
        cid = w.register_channel(THERMOCOUPLES, "protobuf", sid)
        for i in range(5):
            w.add_message(cid, T0 + i * 10**9, b"\x08\x96\x01", T0 + i * 10**9)
        w.finish()
    return path
