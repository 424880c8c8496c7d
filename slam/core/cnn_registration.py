"""CNN point-cloud registration (paper section VII-A).

Two consecutive clouds are rasterised into grid maps and a small CNN -- one
convolutional layer, one max-pooling layer, two fully connected layers, as in
the paper -- regresses the motion ``(dx, dy, dheading)`` of the current vehicle
frame in the previous one (metres, radians). Training minimises the paper's loss

    L = mean_n( ||t_hat_n - t_n||^2 + gamma_r ||r_hat_n - r_n||^2 ).

Design decision (docs/design/physics.md, registration): the previous cloud is first moved
into the current frame with a motion *prior* (constant velocity from the last
estimate), so the network regresses the residual motion, a bounded quantity,
whatever the vehicle speed and cycle length. With a zero prior this is exactly
the paper's formulation.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rhs_common.geometry import compose, points_in_frame
from rhs_common.validation import check_int, check_range, check_types

DEFAULT_WEIGHTS = Path(__file__).parent.parent / "data" / "registration_cnn.pt"


@dataclass(frozen=True)
class GridMapConfig:
    """Grid map of a cloud in the vehicle frame: ``cells x cells`` squares of ``cell_m`` metres, centred on the vehicle."""

    cells: int = 64
    cell_m: float = 1.5

    def __post_init__(self) -> None:
        check_types(self)
        check_int("cells", self.cells, 8, 512)
        check_range("cell_m", self.cell_m, 0.0, 20.0, low_open=True)

    @property
    def half_extent_m(self) -> float:
        return 0.5 * self.cells * self.cell_m


def grid_map(points: np.ndarray, cfg: GridMapConfig) -> np.ndarray:
    """Rasterise a cloud (N, >=2) into a (cells, cells) float32 map by bilinear splatting.

    Each point deposits weight 1 (the amplitude varies over orders of magnitude
    with range; occupancy is the robust input), spread over its four nearest
    cells so that sub-cell positions are preserved. Row index follows x, column y.
    """
    out = np.zeros((cfg.cells, cfg.cells), dtype=np.float32)
    if len(points) == 0:
        return out
    g = (np.asarray(points, dtype=float)[:, :2] + cfg.half_extent_m) / cfg.cell_m - 0.5
    i0 = np.floor(g).astype(int)
    f = g - i0
    for di in (0, 1):
        for dj in (0, 1):
            w = (f[:, 0] if di else 1 - f[:, 0]) * (f[:, 1] if dj else 1 - f[:, 1])
            ii, jj = i0[:, 0] + di, i0[:, 1] + dj
            ok = (ii >= 0) & (ii < cfg.cells) & (jj >= 0) & (jj < cfg.cells)
            np.add.at(out, (ii[ok], jj[ok]), w[ok].astype(np.float32))
    return out


def pair_input(prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray, cfg: GridMapConfig) -> np.ndarray:
    """The CNN input (2, cells, cells): previous cloud moved by the prior, current cloud."""
    prev_xy = points_in_frame(np.asarray(prev_points)[:, :2], prior) if len(prev_points) else np.zeros((0, 2))
    return np.stack([grid_map(prev_xy, cfg), grid_map(np.asarray(points)[:, :2], cfg)])


def _torch():
    import torch  # deferred: importing slam must not require loading torch

    return torch


def build_network(cfg: GridMapConfig, channels: int = 16, kernel: int = 5, pool: int = 4, hidden: int = 128):
    """conv(2 -> channels, kernel) + ReLU -> maxpool(pool) -> fc(hidden) + ReLU -> fc(3)."""
    nn = _torch().nn
    if cfg.cells % pool:
        raise ValueError(f"cells={cfg.cells} must be divisible by pool={pool}")
    flat = channels * (cfg.cells // pool) ** 2
    return nn.Sequential(
        nn.Conv2d(2, channels, kernel, padding=kernel // 2),
        nn.ReLU(),
        nn.MaxPool2d(pool),
        nn.Flatten(),
        nn.Linear(flat, hidden),
        nn.ReLU(),
        nn.Linear(hidden, 3),
    )


@dataclass(frozen=True)
class CNNTrainConfig:
    """Training settings; ``gamma_r`` weighs the rotation term of the paper's loss (rad^-2 m^2)."""

    epochs: int = 30
    batch_size: int = 64
    learning_rate: float = 1e-3
    gamma_r: float = 100.0
    channels: int = 16
    hidden: int = 128
    seed: int = 0

    def __post_init__(self) -> None:
        check_types(self)
        check_int("epochs", self.epochs, 1, 10_000)
        check_int("batch_size", self.batch_size, 1, 65_536)
        check_range("learning_rate", self.learning_rate, 0.0, 1.0, low_open=True)
        check_range("gamma_r", self.gamma_r, 0.0, None)
        check_int("channels", self.channels, 1, 256)
        check_int("hidden", self.hidden, 1, 4096)


class CNNRegistration:
    """Registration by the trained CNN; ``estimate(prev, cur, prior) -> (dx, dy, dheading)``.

    The network regresses ``target / scale`` where ``target`` is the residual
    motion after the prior; ``scale`` (3,) is stored with the weights.
    """

    def __init__(self, weights: str | Path | None = None, grid: GridMapConfig | None = None):
        torch = _torch()
        path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        if not path.exists():
            raise FileNotFoundError(
                f"CNN registration weights not found at {path}; train them with scripts/train_registration.py"
            )
        blob = torch.load(path, map_location="cpu", weights_only=False)
        meta = blob["meta"]
        self.grid = grid or GridMapConfig(**meta["grid"])
        if asdict(self.grid) != meta["grid"]:
            raise ValueError(f"{path}: weights were trained for grid {meta['grid']}, not {asdict(self.grid)}")
        self.scale = np.asarray(meta["scale"], dtype=float)
        self.meta = meta
        self.net = build_network(self.grid, meta["channels"], hidden=meta["hidden"])
        self.net.load_state_dict(blob["state_dict"])
        self.net.eval()
        torch.set_num_threads(max(1, torch.get_num_threads()))

    def estimate(self, prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
        prior = np.zeros(3) if prior is None else np.asarray(prior, dtype=float)
        return self.estimate_batch([prev_points], [points], prior[None])[0]

    def estimate_batch(self, prev_list, cur_list, priors: np.ndarray) -> np.ndarray:
        torch = _torch()
        x = np.stack([pair_input(p, c, pr, self.grid) for p, c, pr in zip(prev_list, cur_list, priors)])
        with torch.no_grad():
            res = self.net(torch.from_numpy(x)).numpy().astype(float) * self.scale
        return np.stack([compose(pr, r) for pr, r in zip(priors, res)])


def train_cnn(
    inputs: np.ndarray,
    targets: np.ndarray,
    grid: GridMapConfig,
    cfg: CNNTrainConfig,
    val_inputs: np.ndarray | None = None,
    val_targets: np.ndarray | None = None,
    out: str | Path | None = None,
    progress: bool = True,
) -> dict:
    """Train on (n, 2, cells, cells) inputs and (n, 3) residual-motion targets with the paper's loss.

    Returns the history (train/validation loss per epoch) and, when ``out`` is
    given, saves ``{"state_dict", "meta"}`` there.
    """
    torch = _torch()
    from tqdm.auto import tqdm

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    scale = np.maximum(np.std(targets, axis=0), 1e-3)
    net = build_network(grid, cfg.channels, hidden=cfg.hidden)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs)
    x_all = torch.from_numpy(np.asarray(inputs, dtype=np.float32))
    y_all = torch.from_numpy((np.asarray(targets) / scale).astype(np.float32))
    scale_t = torch.from_numpy(scale.astype(np.float32))
    w = torch.tensor([1.0, 1.0, cfg.gamma_r])

    def paper_loss(pred, y):
        err = (pred - y) * scale_t  # back to metres / radians
        return ((err**2) * w).sum(dim=1).mean()

    history: dict[str, list[float]] = {"train_loss": [], "val_loss": []}
    bar = tqdm(range(cfg.epochs), desc="train CNN", disable=not progress)
    for _ in bar:
        net.train()
        perm = rng.permutation(len(x_all))
        total = 0.0
        for k in range(0, len(perm), cfg.batch_size):
            idx = torch.from_numpy(perm[k : k + cfg.batch_size])
            opt.zero_grad()
            loss = paper_loss(net(x_all[idx]), y_all[idx])
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        sched.step()
        history["train_loss"].append(total / len(perm))
        if val_inputs is not None:
            net.eval()
            with torch.no_grad():
                vx = torch.from_numpy(np.asarray(val_inputs, dtype=np.float32))
                vy = torch.from_numpy((np.asarray(val_targets) / scale).astype(np.float32))
                history["val_loss"].append(float(paper_loss(net(vx), vy)))
            bar.set_postfix(train=f"{history['train_loss'][-1]:.4f}", val=f"{history['val_loss'][-1]:.4f}")
    if out is not None:
        meta = {
            "grid": asdict(grid),
            "scale": scale.tolist(),
            "channels": cfg.channels,
            "hidden": cfg.hidden,
            "train": asdict(cfg),
            "history": history,
        }
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        # float16 halves the shipped file; the loss of precision is far below the regression error.
        state = {k: v.half() for k, v in net.state_dict().items()}
        torch.save({"state_dict": state, "meta": meta}, out)
        _ = json.dumps(meta)  # meta must stay JSON-serialisable (shown by the training script)
    return {"history": history, "scale": scale, "net": net}
