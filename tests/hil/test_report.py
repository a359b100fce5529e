"""The benchmark report from synthetic ticks: definitions, rate verdict, table and histogram."""

import json

import pytest

from hil_sim import report


def ticks(n=101, rate=10.0, *, late=(), missing=()):
    rows, cmds = [], []
    for k in range(n):
        t = 100.0 + k / rate
        rows.append({"tick": k, "deadline": t + 0.05, "late": k in late, "cmd_seq": k, "t_capture": t - 0.04,
                     "t_receive": t, "t_preprocess": t + 0.002, "t_inference": t + 0.012, "t_send": t + 0.013,
                     "frame": k})
        if k not in missing:
            cmds.append({"seq": k, "t_receive": t + 0.014})
    return rows, cmds


def test_definitions_of_every_latency():
    rows, cmds = ticks()
    doc = report.build(rows, cmds, rate_hz=10.0, usage=report.Usage(50.0, 100.0))
    assert doc["latency_ms"]["p50"] == pytest.approx(14.0, abs=1e-6)
    assert doc["frame_age_ms"]["p99"] == pytest.approx(42.0, abs=1e-6)
    assert doc["capture_to_command_ms"]["max"] == pytest.approx(54.0, abs=1e-6)
    assert doc["stages_ms"]["inference"]["p50"] == pytest.approx(10.0, abs=1e-6)
    assert doc["rate_hz_achieved"] == pytest.approx(10.0) and report.rate_held(doc)
    assert set(doc) >= {"rate_hz_target", "rate_hz_achieved", "ticks", "late_ticks", "latency_ms",
                        "frame_age_ms", "capture_to_command_ms", "stages_ms", "cpu_percent", "rss_mb"}
    json.dumps(doc)


@pytest.mark.parametrize("kw", [{"late": (5,)}, {"missing": tuple(range(50, 101))}, {"rate": 10.5}])
def test_rate_not_held(kw):
    rate = kw.pop("rate", 10.0)
    rows, cmds = ticks(rate=rate, **kw)
    assert not report.rate_held(report.build(rows, cmds, rate_hz=10.0, usage=report.Usage(0, 0)))


def test_a_run_may_allow_a_share_of_late_ticks_and_no_more():
    def doc(late):
        rows, cmds = ticks(late=late)  # 101 ticks: a share of 0.01 allows one
        return report.build(rows, cmds, rate_hz=10.0, usage=report.Usage(0, 0), late_share=0.01)

    assert report.rate_held(doc((5,))) and "1 late (up to 1 allowed) -> HELD" in report.table(doc((5,)))
    assert not report.rate_held(doc((5, 6)))


def test_table_and_histogram(tmp_path):
    rows, cmds = ticks(late=(3, 7), missing=(7,))  # a late tick whose command never came is marked too
    doc = report.build(rows, cmds, rate_hz=10.0, usage=report.Usage(1, 2))
    assert "NOT HELD" in report.table(doc) and "latency_ms" in report.table(doc)
    report.histogram(rows, cmds, tmp_path / "h.png", title="t", rate_hz=10.0, camera_fps=5.0)
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"


def test_the_caption_explains_frame_age_only_when_the_camera_is_slower_than_the_loop():
    assert report.frame_age_caption(10.0, 15.0) is None and report.frame_age_caption(10.0, None) is None
    caption = report.frame_age_caption(10.0, 4.96)
    assert "4.96 fps" in caption and "slower than the loop (10 Hz)" in caption and "two clusters" in caption


def test_bad_metrics_file_is_a_report_error(tmp_path):
    (tmp_path / "m.jsonl").write_text("{not json\n")
    with pytest.raises(report.ReportError, match="m.jsonl"):
        report.load_ticks(tmp_path / "m.jsonl")
    with pytest.raises(report.ReportError, match="no ticks"):
        (tmp_path / "e.jsonl").write_text("")
        report.load_ticks(tmp_path / "e.jsonl")
