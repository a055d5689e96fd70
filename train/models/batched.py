"""Train many small MLPs at once: M independent 3-layer nets (in -> hidden ReLU -> out) whose weights
are stacked as (M, in, out) tensors and evaluated with torch.baddbmm, one optimiser step per
minibatch for all of them.

Each model m has its own training rows (a different subset, even of a different size), its own
input/output standardisation (from its rows), its own initialisation and minibatch order (from its own
seed), its own Adam state and step count, and its own best-validation-epoch weights. Per epoch model m
takes ceil(n_m / batch_size) steps over a fresh permutation of its rows (the last batch may be short);
the whole batch runs max_m of that many steps and a model whose epoch is over sits the rest out
(no gradient, no Adam step). So every model follows exactly the trajectory the plain one-model loop
`train_plain` follows with the same seed; only floating-point summation order differs (the gradients
are written out rather than taken through autograd, and Adam runs on all models' parameters as one
(M, P) tensor: docs/train.md, "The sweep").

Loss per model on a minibatch (the per-model terms of train.models.losses.weighted_loss):
sum_ij w_ij (y_ij - yhat_ij)^2 / (J n) in standardised units,
w = the dead-zone mask r for the masked loss (eq. 3), w = 1 for MSE.
Validation (every epoch): MSE in SI units on the validation rows, averaged over joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from .mlp_settings import DEFAULT_BATCH_SIZE, MLPSettings  # noqa: F401 (their home before)

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

@dataclass
class BatchedResult:
    params: dict  # best-epoch weights: W1 (M, D, H), b1 (M, H), W2 (M, H, J), b2 (M, J) numpy float32
    norm: dict  # x_mean, x_std (M, D), y_mean, y_std (M, J)
    best_epoch: np.ndarray  # (M,) 0-based epoch whose weights were kept
    best_val: np.ndarray  # (M,) validation MSE (SI, mean over joints) at that epoch
    train_loss: np.ndarray  # (epochs, M) mean minibatch loss per epoch
    val_mse: np.ndarray  # (epochs, M, J) validation MSE per joint per epoch

    def model(self, m: int) -> tuple[dict, dict]:
        """(params, norm) of model m alone (leading dimension 1)."""
        return ({k: v[m:m + 1] for k, v in self.params.items()},
                {k: v[m:m + 1] for k, v in self.norm.items()})


def init_params(rng: np.random.Generator, d_in: int, hidden: int, d_out: int) -> dict:
    """PyTorch's default nn.Linear initialisation, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), from `rng`."""
    k1, k2 = 1 / math.sqrt(d_in), 1 / math.sqrt(hidden)
    return {"W1": rng.uniform(-k1, k1, (d_in, hidden)).astype(np.float32),
            "b1": rng.uniform(-k1, k1, hidden).astype(np.float32),
            "W2": rng.uniform(-k2, k2, (hidden, d_out)).astype(np.float32),
            "b2": rng.uniform(-k2, k2, d_out).astype(np.float32)}


def standardisation(X: np.ndarray, Y: np.ndarray, rows: np.ndarray) -> dict:
    xs, ys = X[rows], Y[rows]
    x_std = xs.std(axis=0)
    y_std = ys.std(axis=0)
    return {"x_mean": xs.mean(axis=0).astype(np.float32),
            "x_std": np.where(x_std > 1e-12, x_std, 1.0).astype(np.float32),
            "y_mean": ys.mean(axis=0).astype(np.float32),
            "y_std": np.where(y_std > 1e-12, y_std, 1.0).astype(np.float32)}


def forward(params: dict, x: torch.Tensor) -> torch.Tensor:
    """x (M, B, D) standardised -> (M, B, J) standardised outputs."""
    h = torch.relu(torch.baddbmm(params["b1"].unsqueeze(1), x, params["W1"]))
    return torch.baddbmm(params["b2"].unsqueeze(1), h, params["W2"])


def predict(params: dict, norm: dict, X: np.ndarray) -> np.ndarray:
    """SI inputs (N, D) -> SI outputs (M, N, J) for every stacked model."""
    p = {k: torch.as_tensor(v) for k, v in params.items()}
    n = {k: torch.as_tensor(v) for k, v in norm.items()}
    x = torch.as_tensor(np.asarray(X, dtype=np.float32))
    with torch.no_grad():
        xs = (x.unsqueeze(0) - n["x_mean"].unsqueeze(1)) / n["x_std"].unsqueeze(1)
        y = forward(p, xs) * n["y_std"].unsqueeze(1) + n["y_mean"].unsqueeze(1)
    return y.numpy()


def _epoch_batches(orders, batch_size):
    """(S, M, B) row indices (-1 = padding) for one epoch from each model's permutation."""
    steps = max(math.ceil(len(o) / batch_size) for o in orders)
    idx = np.full((len(orders), steps * batch_size), -1, dtype=np.int64)
    for m, o in enumerate(orders):
        idx[m, :len(o)] = o
    return idx.reshape(len(orders), steps, batch_size).transpose(1, 0, 2)


def train_mlps(X: np.ndarray, Y: np.ndarray, W: np.ndarray, rows: Sequence[np.ndarray], X_val: np.ndarray,
               Y_val: np.ndarray, settings: MLPSettings | None = None, seeds: Sequence[int] | None = None,
               progress: Callable[[int, int], object] | None = None, W_val: np.ndarray | None = None
               ) -> BatchedResult:
    """Train len(rows) MLPs together.

    X (N, D), Y (N, J), W (N, J) loss weights (mask or ones), rows: list of M index arrays (each model's
    training rows), X_val (V, D), Y_val (V, J) SI validation data, seeds: M ints (default 0..M-1),
    progress: optional callable(epoch_done, epochs) for progress bars. W_val (V, J) bool: score each
    joint's validation MSE over its True rows only (a per-joint validation set, train.data.splits); None: all.
    """
    s = settings or MLPSettings()
    M = len(rows)
    seeds = list(range(M)) if seeds is None else list(seeds)
    D, J, H = X.shape[1], Y.shape[1], s.hidden
    rngs = [np.random.default_rng(sd) for sd in seeds]
    inits = [init_params(r, D, H, J) for r in rngs]
    norms = [standardisation(X, Y, np.asarray(r)) for r in rows]
    norm = {k: np.stack([n[k] for n in norms]) for k in norms[0]}
    nt = {k: torch.as_tensor(v) for k, v in norm.items()}
    # one table [X | Y | W] so that a minibatch is one gather; padding row N: zeros, weight 0
    # (per-model standardised copies of the data would cost M x N; standardise per batch instead)
    table = torch.as_tensor(np.vstack([
        np.hstack([np.asarray(X, dtype=np.float32), np.asarray(Y, dtype=np.float32),
                   np.asarray(W, dtype=np.float32)]),
        np.zeros((1, D + 2 * J), dtype=np.float32)]))
    xv = torch.as_tensor(np.asarray(X_val, dtype=np.float32))
    yv = torch.as_tensor(np.asarray(Y_val, dtype=np.float32))
    xv_std = (xv.unsqueeze(0) - nt["x_mean"].unsqueeze(1)) / nt["x_std"].unsqueeze(1)  # (M, V, D)
    if W_val is not None:
        wv = torch.as_tensor(np.asarray(W_val, dtype=np.float32))  # (V, J)
        wv_n = wv.sum(dim=0).clamp(min=1)

    # All of a model's parameters in one row of `flat` (W1, b1, W2 transposed, b2), so that Adam is a few
    # element-wise operations on (M, P) tensors instead of a few per parameter tensor. The matmuls take
    # contiguous copies (a strided view makes the CPU batched matmul several times slower); W2 is kept as
    # (M, J, H) because the batched matmul of (B, H) by (H, J) with J = 3 is ~3x faster with that layout.
    # The gradients are written out (a 2-layer ReLU network), not taken through autograd.
    flat, views = _flat_params(inits, D, H, J)
    exp_avg, exp_sq = torch.zeros_like(flat), torch.zeros_like(flat)
    steps_done = np.zeros(M)
    best = flat.clone()
    best_val = torch.full((M,), float("inf"))
    best_epoch = np.zeros(M, dtype=int)
    train_loss = np.zeros((s.epochs, M))
    val_mse = np.zeros((s.epochs, M, J))
    rows = [np.asarray(r, dtype=np.int64) for r in rows]
    sizes = np.array([len(r) for r in rows])
    pad = len(X)
    x_mean, x_std = nt["x_mean"].unsqueeze(1), nt["x_std"].unsqueeze(1)
    y_mean, y_std = nt["y_mean"].unsqueeze(1), nt["y_std"].unsqueeze(1)
    xs, ys, ws = slice(0, D), slice(D, D + J), slice(D + J, D + 2 * J)

    def net(x):  # x (M, B, D) standardised -> (hidden, output, W2t)
        w1, w2t = views["W1"].contiguous(), views["W2t"].contiguous()
        hidden = torch.baddbmm(views["b1"].unsqueeze(1), x, w1).relu_()  # in place: a fresh 25 MB output
        # (the validation pass) costs ~4x more to write than to update
        return hidden, torch.baddbmm(views["b2"].unsqueeze(1), hidden, w2t.transpose(1, 2)), w2t

    with torch.no_grad():
        for epoch in range(s.epochs):
            orders = [r[rng.permutation(len(r))] for r, rng in zip(rows, rngs)]
            batches = torch.as_tensor(_epoch_batches(orders, s.batch_size))
            batches = torch.where(batches < 0, pad, batches)
            f = _step_factors(sizes, len(batches), s, steps_done, J)
            steps_done = steps_done + np.ceil(sizes / s.batch_size)
            loss_sum = torch.zeros(M)
            for k, idx in enumerate(batches):  # idx (M, B)
                batch = table[idx]
                xb = (batch[..., xs] - x_mean) / x_std
                werr_scale = f["grad_scale"][k]
                hidden, out, w2t = net(xb)
                err = out - (batch[..., ys] - y_mean) / y_std
                werr = batch[..., ws] * err
                loss_sum += (werr * err).sum(dim=(1, 2)) * f["loss_scale"][k]
                # d(sum of the models' losses)/d(out), then back through the two layers
                d_out = werr * werr_scale  # (M, B, J)
                d_pre = torch.ops.aten.threshold_backward(torch.bmm(d_out, w2t), hidden, 0)  # (M, B, H)
                grad = torch.cat([torch.bmm(xb.transpose(1, 2), d_pre).view(M, -1), d_pre.sum(dim=1),
                                  torch.bmm(d_out.transpose(1, 2), hidden).view(M, -1), d_out.sum(dim=1)],
                                 dim=1)
                # Adam; a model whose epoch is over (factors 1 and 0) keeps its moments and weights
                exp_avg.mul_(f["keep1"][k]).add_(grad * f["take1"][k])
                exp_sq.mul_(f["keep2"][k]).addcmul_(grad * f["take2"][k], grad)
                flat.sub_(exp_avg * f["lr"][k] / exp_sq.sqrt().mul_(f["unbias2"][k]).add_(s.eps))
            pred = net(xv_std)[1] * y_std + y_mean
            if W_val is None:
                vm = ((pred - yv.unsqueeze(0)) ** 2).mean(dim=1)  # (M, J)
            else:
                vm = (wv * (pred - yv.unsqueeze(0)) ** 2).sum(dim=1) / wv_n
            score = vm.mean(dim=1)
            better = score < best_val
            if better.any():
                best = torch.where(better.view(M, 1), flat, best)
                best_val = torch.where(better, score, best_val)
                best_epoch[better.numpy()] = epoch
            train_loss[epoch] = loss_sum.numpy() / np.maximum(np.ceil(sizes / s.batch_size), 1)
            val_mse[epoch] = vm.numpy()
            if progress is not None:
                progress(epoch + 1, s.epochs)
    kept = _views(best, M, D, H, J)
    params = {"W1": kept["W1"], "b1": kept["b1"], "W2": kept["W2t"].transpose(1, 2), "b2": kept["b2"]}
    return BatchedResult({k: np.ascontiguousarray(v.numpy()) for k, v in params.items()}, norm, best_epoch,
                         best_val.numpy().copy(), train_loss, val_mse)


def _step_factors(sizes: np.ndarray, n_steps: int, s: MLPSettings, steps_done: np.ndarray, J: int) -> dict:
    """Per minibatch step k of one epoch, (M, 1[, 1]) float32 tensors: the loss and gradient scales
    (1 / (J n) of each model's batch) and the Adam factors (moment decay and bias corrections, 1 and 0
    for a model whose epoch is over), computed for the whole epoch at once."""
    k = np.arange(n_steps)[:, None]
    count = np.clip(sizes[None, :] - k * s.batch_size, 0, s.batch_size).astype(float)  # (S, M)
    active = (count > 0).astype(float)
    step = steps_done[None, :] + np.minimum(k + 1, np.ceil(sizes / s.batch_size)[None, :])
    step = np.maximum(step, 1)
    b1, b2 = s.betas
    return {name: torch.as_tensor(v.astype(np.float32)).view(n_steps, -1, *shape) for name, v, shape in (
        ("loss_scale", active / (J * np.maximum(count, 1)), ()),
        ("grad_scale", 2.0 * active / (J * np.maximum(count, 1)), (1, 1)),
        ("keep1", 1 - active * (1 - b1), (1,)),
        ("take1", active * (1 - b1), (1,)),
        ("keep2", 1 - active * (1 - b2), (1,)),
        ("take2", active * (1 - b2), (1,)),
        ("lr", active * s.lr / (1 - b1 ** step), (1,)),
        ("unbias2", 1 / np.sqrt(1 - b2 ** step), (1,)),
    )}


def _views(flat: torch.Tensor, M: int, D: int, H: int, J: int) -> dict:
    """W1 (M, D, H), b1 (M, H), W2t (M, J, H), b2 (M, J) as views of the rows of `flat` (M, P)."""
    sizes = {"W1": (D, H), "b1": (H,), "W2t": (J, H), "b2": (J,)}
    out, at = {"_flat": flat}, 0
    for name, shape in sizes.items():
        n = math.prod(shape)
        out[name] = flat[:, at:at + n].view((M, *shape))
        at += n
    return out


def _flat_params(inits: list[dict], D: int, H: int, J: int) -> tuple[torch.Tensor, dict]:
    """The initial parameters of every model, one row each (see _views)."""
    rows = [np.concatenate([p["W1"].ravel(), p["b1"], p["W2"].T.ravel(), p["b2"]]) for p in inits]
    flat = torch.tensor(np.stack(rows).astype(np.float32))
    views = _views(flat, len(inits), D, H, J)
    views.pop("_flat")
    return flat, views


def train_plain(X: np.ndarray, Y: np.ndarray, W: np.ndarray, rows: np.ndarray | Sequence[int],
                X_val: np.ndarray, Y_val: np.ndarray, settings: MLPSettings | None = None,
                seed: int = 0) -> BatchedResult:
    """Reference: one model trained the ordinary way (nn.Sequential, torch.optim.Adam, a Python loop over
    minibatches), same initialisation, minibatch order and loss as `train_mlps` with seeds=[seed].
    Used by the equivalence test and the benchmark; returns a BatchedResult with M = 1."""
    s = settings or MLPSettings()
    rows = np.asarray(rows, dtype=np.int64)
    D, J, H = X.shape[1], Y.shape[1], s.hidden
    rng = np.random.default_rng(seed)
    init = init_params(rng, D, H, J)
    net = torch.nn.Sequential(torch.nn.Linear(D, H), torch.nn.ReLU(), torch.nn.Linear(H, J))
    with torch.no_grad():
        net[0].weight.copy_(torch.as_tensor(init["W1"].T))
        net[0].bias.copy_(torch.as_tensor(init["b1"]))
        net[2].weight.copy_(torch.as_tensor(init["W2"].T))
        net[2].bias.copy_(torch.as_tensor(init["b2"]))
    norm = standardisation(X, Y, rows)
    xs = torch.as_tensor(((X - norm["x_mean"]) / norm["x_std"]).astype(np.float32))
    ys = torch.as_tensor(((Y - norm["y_mean"]) / norm["y_std"]).astype(np.float32))
    ws = torch.as_tensor(np.asarray(W, dtype=np.float32))
    xv = torch.as_tensor(((X_val - norm["x_mean"]) / norm["x_std"]).astype(np.float32))
    yv = torch.as_tensor(np.asarray(Y_val, dtype=np.float32))
    y_mean, y_std = torch.as_tensor(norm["y_mean"]), torch.as_tensor(norm["y_std"])
    opt = torch.optim.Adam(net.parameters(), lr=s.lr, betas=s.betas, eps=s.eps)
    best_state, best_val, best_epoch = None, float("inf"), 0
    train_loss = np.zeros((s.epochs, 1))
    val_mse = np.zeros((s.epochs, 1, J))
    for epoch in range(s.epochs):
        order = rows[rng.permutation(len(rows))]
        losses = []
        for start in range(0, len(order), s.batch_size):
            b = torch.as_tensor(order[start:start + s.batch_size])
            out = net(xs[b])
            loss = (ws[b] * (out - ys[b]) ** 2).sum() / (J * len(b))
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
        with torch.no_grad():
            vm = ((net(xv) * y_std + y_mean - yv) ** 2).mean(dim=0)
        train_loss[epoch, 0] = np.mean(losses)
        val_mse[epoch, 0] = vm.numpy()
        if vm.mean().item() < best_val:
            best_val, best_epoch = vm.mean().item(), epoch
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
    params = {"W1": best_state["0.weight"].T.numpy()[None], "b1": best_state["0.bias"].numpy()[None],
              "W2": best_state["2.weight"].T.numpy()[None], "b2": best_state["2.bias"].numpy()[None]}
    return BatchedResult(params, {k: v[None] for k, v in norm.items()}, np.array([best_epoch]),
                         np.array([best_val]), train_loss, val_mse)
