"""L2-SP: a fine-tune held near the weights it started from (Li, Grandvalet, Davoine 2018, "Explicit inductive bias
for transfer learning with convolutional networks").

With ``train.sp_weight`` = alpha > 0 each step's loss gains

    alpha / 2 * ||w - w_start||^2

over every trainable parameter, ``w_start`` the weights the run started from (``--init``: the shipped model for
the sensor-mix fine-tunes). Plain weight decay pulls towards 0, which for a fine-tune means away from what the
network knew; this pulls towards the start, so the new data moves the weights only as far as its gradient
outweighs ``alpha`` times the distance. The gradient of the term is ``alpha (w - w_start)``: at a distance ``d``
from the start it is as strong as a loss gradient of norm ``alpha d``.

The start is stored in the training state (``sp_anchor``, about the size of the model), so a resumed run is held
to the same weights; a run resumed with the term on from a state saved without it is held to the weights it
resumed with.
"""

from __future__ import annotations

from typing import Any


def anchor_of(model) -> dict[str, Any]:
    """Detached copies of ``model``'s trainable parameters, by name: the weights the penalty pulls towards."""
    return {name: p.detach().clone() for name, p in model.named_parameters() if p.requires_grad}


def sp_distance2(model, anchor: dict[str, Any]):
    """``||w - w_start||^2`` (0-d tensor with the gradient) over ``model``'s trainable parameters named in
    ``anchor``."""
    import torch

    total = None
    for name, p in model.named_parameters():
        if p.requires_grad:
            a = anchor[name].to(device=p.device, dtype=p.dtype)
            term = ((p - a) ** 2).sum()
            total = term if total is None else total + term
    return total if total is not None else torch.zeros(())
