"""Training DeepBBS++ for LiDAR: a frame cache, augmented pairs with ground truth, the paper's loss,
a resumable training loop and the evaluation behind the model card (no ROS import)."""

from deepbbs_ros.train.cache import Drive, load_cache, load_drive
from deepbbs_ros.train.loss import LossTerms, deepbbs_loss, partner_mask
from deepbbs_ros.train.pairs import AugmentConfig, Pair, PairSampler, collate, make_pair, validation_pairs
from deepbbs_ros.train.trainer import Trainer

__all__ = [
    "AugmentConfig", "Drive", "LossTerms", "Pair", "PairSampler", "Trainer", "collate", "deepbbs_loss",
    "load_cache", "load_drive", "make_pair", "partner_mask", "validation_pairs",
]
