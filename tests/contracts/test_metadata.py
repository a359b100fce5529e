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
])
def test_bad_metadata_is_refused(edit, match):
    d = json.loads(PolicyMetadata(preprocess=DepthSpec()).to_json())
    with pytest.raises(MetadataError, match=match):
        PolicyMetadata.from_json(json.dumps(edit(d)))


def test_files_from_before_the_spacing_field_read_as_leading():
    d = json.loads(PolicyMetadata(preprocess=DepthSpec(), ddim_spacing="trailing").to_json())
    del d["ddim_spacing"]
    assert PolicyMetadata.from_json(json.dumps(d)).ddim_spacing == "leading"


def test_files_exported_while_first_frame_existed_load_unless_they_set_it():
    """Files from 2026-11-25 on carry ``first_frame``: false reads as any other file; a first-frame student
    (4 depth channels) is refused in one line."""
    d = json.loads(PolicyMetadata(preprocess=DepthSpec()).to_json())
    assert PolicyMetadata.from_json(json.dumps(d | {"first_frame": False})) == PolicyMetadata.from_json(
        json.dumps(d))
    for value in (True, 1):
        with pytest.raises(MetadataError, match="^first_frame students are no longer supported") as refused:
            PolicyMetadata.from_json(json.dumps(d | {"first_frame": value}))
        assert "\n" not in str(refused.value)


def test_not_json():
    with pytest.raises(MetadataError, match="JSON"):
        PolicyMetadata.from_json("{nope")
    assert SCHEMA.endswith("/1")
