#!/usr/bin/env python3
"""Write the weights of a `deepbbs-train fit` state file (state_latest.pt) as a checkpoint that `--weights`
takes, with the config stored in that state, so a run's latest step can be evaluated like a shipped model:

    python scripts/state_weights.py deepbbs_ros/models/train_state/worlds/state_latest.pt runs/worlds_4856.pt
    deepbbs-train evaluate --weights runs/worlds_4856.pt --methods deepbbs --threads 1
"""
from __future__ import annotations

import argparse


def main() -> None:
    import torch

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.checkpoint import save_checkpoint
    from deepbbs_ros.core.model import DeepBBSNet

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("state", help="a deepbbs-train state file (state_latest.pt)")
    ap.add_argument("out", help="checkpoint to write")
    args = ap.parse_args()
    state = torch.load(args.state, map_location="cpu", weights_only=False)
    config = Config.from_dict(state["config"])
    model = DeepBBSNet(config.model)
    model.load_state_dict(state["model"])
    save_checkpoint(args.out, model, config, {"step": int(state["step"]), "source_state": str(args.state)})
    print(f"{args.out}: step {state['step']} of {args.state}")


if __name__ == "__main__":
    main()
