"""The validation pairs are shared out over the validation folders before they are cut to ``max_pairs``."""

import numpy as np

from deepbbs_ros.train.pairs import Pair
from deepbbs_ros.train.validation import _shared_out


def _pair(drive: str, k: int) -> Pair:
    z = np.zeros((1, 3), np.float32)
    return Pair(source=z, target=z, T_target_source=np.eye(4), scene="urban", ref=f"{drive}:{k}->{k + 1}")


def test_every_folder_kept_when_cut():
    # 16 mix drives listed before 8 road drives, one pair each, cut to 12: both folders must be validated
    pairs = [_pair(f"mix_{i}", 0) for i in range(16)] + [_pair(f"road_{i}", 0) for i in range(8)]
    folder = {**{f"mix_{i}": "cache/mix_val" for i in range(16)}, **{f"road_{i}": "cache/worlds_val" for i in range(8)}}
    kept = _shared_out(pairs, folder)[:12]
    names = [p.ref.split(":")[0] for p in kept]
    assert sum(n.startswith("road") for n in names) == 6 and sum(n.startswith("mix") for n in names) == 6
    assert [n for n in names if n.startswith("mix")] == [f"mix_{i}" for i in range(6)]  # each folder in its order
    assert sorted(p.ref for p in _shared_out(pairs, folder)) == sorted(p.ref for p in pairs)  # nothing lost


def test_one_folder_unchanged():
    pairs = [_pair(f"d_{i}", k) for i in range(5) for k in range(3)]
    folder = {f"d_{i}": "cache/val" for i in range(5)}
    assert [p.ref for p in _shared_out(pairs, folder)] == [p.ref for p in pairs]
