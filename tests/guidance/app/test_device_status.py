"""One health record from the driver to the driver's ear and the monitor (issue 11, change 3):
a status only the driver knows ("disconnected") reaches the pipeline through the ordinary
message path, is spoken once in the sentence table's words for that input and status
(guidance.core.speech: the driver reports a status, never a sentence), and shows in the
input's health."""

from __future__ import annotations

import asyncio
import io
from pathlib import Path

from drivers.compass import SerialCompass, SerialCompassConfig
from guidance.app.app import App
from guidance.app.settings import LoopSettings
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import DeviceStatus, Health, Say, Speech
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import NavigatorConfig
from guidance.outputs.messages import health_message
from guidance.voice.speakers import TextSpeaker


def _pipeline() -> Pipeline:
    return Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=(500.0, 0.0),
            start_heading_rad=0.0,
            expected_rates_hz={"compass": 10.0},
        )
    )


def test_a_compass_whose_port_is_gone_is_said_disconnected_in_its_own_words(
    tmp_path: Path,
) -> None:
    pipeline = _pipeline()
    speech = io.StringIO()
    compass = SerialCompass(SerialCompassConfig(port=str(tmp_path / "ttyUSB-missing")))

    async def scenario() -> None:
        app = App(pipeline, sources={"compass": compass}, speaker=TextSpeaker(speech),
                  loop=LoopSettings(tick_hz=50))  # fmt: skip
        async with app.running():
            await asyncio.sleep(1.5)

    asyncio.run(scenario())
    said = speech.getvalue()
    assert said.count("Compass disconnected. Heading is getting less certain.") == 1
    assert "Warning: compass" not in said  # not twice, in other words
    st = pipeline.statuses(pipeline.t_s or 0.0)["compass"]
    assert not st.valid and "disconnected" in st.detail and "ttyUSB-missing" in st.detail
    assert st.status == "disconnected" and st.warning.startswith("Compass disconnected.")


def test_a_driver_flip_back_to_ok_clears_it() -> None:
    p = _pipeline()
    warning = "Compass disconnected. Heading is getting less certain."
    bad = Health("serial_compass", "disconnected", False, False, detail="gone")
    out = p.feed(DeviceStatus(1.0, "compass", bad))
    assert [pr.text for pr in out.prompts] == [warning]
    assert out.prompts[0].say == Say(Speech.SENSOR, input="compass", status="disconnected")
    assert p.feed(DeviceStatus(1.5, "compass", bad)).prompts == []  # once per episode
    # the same record, as it is, from the driver through the pipeline to the health message
    st = p.statuses(1.5)["compass"]
    assert (st.status, st.alive, st.valid, st.warning) == ("disconnected", False, False, warning)
    msg = health_message(1.5, p.statuses(1.5), vehicle_id="car1")
    assert msg["ok"] is False and msg["inputs"]["compass"] == st.as_dict()
    assert msg["inputs"]["compass"]["detail"] == "disconnected: gone"
    ok = Health("serial_compass", "ok", True, True)
    p.feed(DeviceStatus(2.0, "compass", ok))
    assert p.health.device_status("compass") == "ok"
    assert p.statuses(2.0)["compass"].status != "disconnected"
