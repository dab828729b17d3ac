"""`scanfuse bag FOLDER|GLOB OUT`: one fused bag per input, each as a single run fuses it; a
malformed bag listed without stopping the others; inputs unchanged."""

from __future__ import annotations

import pytest

from scanfuse.cli import main
from scanfuse.cluster import LocalPool
from scanfuse.config import FusionConfig
from scanfuse.errors import BagError
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.batch import BagOptions, find_bags, fuse_bags, input_digest, is_batch
from tests.support.bag_batch import bag_folder, messages


def test_a_folder_of_bags_is_fused_bag_by_bag(tmp_path):
    good, other, broken = bag_folder(tmp_path / 'in')
    before = {bag: input_digest(bag) for bag in (good, other, broken)}
    report = fuse_bags(tmp_path / 'in', tmp_path / 'out', BagOptions(FusionConfig()), LocalPool(2))
    assert [o.input for o in report.outcomes] == [broken, good, other]  # sorted by name
    assert [o.input for o in report.failed] == [broken]
    assert report.failed[0].error
    assert not (tmp_path / 'out' / 'broken').exists()
    for bag in (good, other):
        single = fuse_bag(bag, tmp_path / f'single-{bag.stem}')
        assert messages(tmp_path / 'out' / bag.stem) == messages(single.output)
        outcome = next(o for o in report.outcomes if o.input == bag)
        assert outcome.scans_fused == single.scans_paired > 0
    assert {bag: input_digest(bag) for bag in before} == before


def test_the_cli_takes_a_glob_and_fails_after_listing_every_bag(tmp_path, capsys):
    _, other, _ = bag_folder(tmp_path / 'in')
    pattern = str(tmp_path / 'in' / '*')
    assert is_batch(pattern)
    assert not is_batch(other)  # a bag folder is one bag
    assert main(['bag', pattern, str(tmp_path / 'out')]) == 1
    captured = capsys.readouterr()
    assert '1 of 3 bags failed' in captured.err
    assert 'failed' in captured.out
    assert (tmp_path / 'out' / 'good' / 'metadata.yaml').exists()
    assert (tmp_path / 'out' / 'other' / 'metadata.yaml').exists()
    assert not (tmp_path / 'out' / 'broken').exists()


def test_batch_inputs_are_checked(tmp_path):
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match='no bags in the folder'):
        find_bags(tmp_path / 'empty')
    with pytest.raises(BagError, match='no bags in the pattern'):
        find_bags(str(tmp_path / '*.mcap'))
    (tmp_path / 'two').mkdir()
    (tmp_path / 'two' / 'a.mcap').write_bytes(b'')
    (tmp_path / 'two' / 'a.db3').write_bytes(b'')
    with pytest.raises(BagError, match='would both be written to'):
        fuse_bags(tmp_path / 'two', tmp_path / 'out', BagOptions(FusionConfig()))
