import json

import pytest

from runtime.metadata import SCHEMA, MetadataError, PolicyMetadata
from runtime.preprocess import DepthSpec


def test_round_trip():
    meta = PolicyMetadata(preprocess=DepthSpec(), ddim_steps=8, training_data={"depth_source": "ddg"})
    assert PolicyMetadata.from_json(meta.to_json()) == meta
    assert meta.input_shapes()["depth"] == [1, 3, 96, 128]


@pytest.mark.parametrize("edit, match", [
    (lambda d: d | {"schema": "diffudepgrasp.policy/0"}, "schema"),
    (lambda d: {k: v for k, v in d.items() if k != "schema"}, "schema"),
    (lambda d: d | {"exec_horizon": 99}, "exec_horizon"),
    (lambda d: d | {"surprise": 1}, "unknown"),
    (lambda d: d | {"preprocess": {"near_m": 3.0}}, "near_m"),
    (lambda d: d | {"ddim_spacing": "linspace"}, "ddim_spacing"),
    (lambda d: d | {"first_frame": 1}, "first_frame"),
])
def test_bad_metadata_is_refused(edit, match):
    d = json.loads(PolicyMetadata(preprocess=DepthSpec()).to_json())
    with pytest.raises(MetadataError, match=match):
        PolicyMetadata.from_json(json.dumps(edit(d)))


def test_files_from_before_the_spacing_field_read_as_leading():
    d = json.loads(PolicyMetadata(preprocess=DepthSpec(), ddim_spacing="trailing").to_json())
    del d["ddim_spacing"]
    assert PolicyMetadata.from_json(json.dumps(d)).ddim_spacing == "leading"


def test_the_first_frame_is_one_more_depth_channel_and_older_files_have_none():
    d = json.loads(PolicyMetadata(preprocess=DepthSpec(), first_frame=True).to_json())
    assert PolicyMetadata.from_json(json.dumps(d)).input_shapes()["depth"] == [1, 4, 96, 128]
    del d["first_frame"]
    assert PolicyMetadata.from_json(json.dumps(d)).input_shapes()["depth"] == [1, 3, 96, 128]


def test_not_json():
    with pytest.raises(MetadataError, match="JSON"):
        PolicyMetadata.from_json("{nope")
    assert SCHEMA.endswith("/1")
