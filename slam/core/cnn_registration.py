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

Weights files are verified when loaded (:func:`load_weights`): read with ``torch.load(weights_only=True)``
(no code runs from the file), checked for the ``state_dict`` / ``meta`` layout, a grid map and scale that
make sense, and tensors of the shapes the network of that grid has; the record written beside them
(``<name>.json``, :func:`weights_record`: sha256 of the file, the grid, the network sizes) must match when
present, and must exist for the shipped weights. A bad file raises ``ValueError`` (``FileNotFoundError`` when
missing) naming it and how to regenerate it (:data:`TRAIN_COMMAND`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.geometry import compose, points_in_frame
from rhs_common.input_files import file_sha256
from rhs_common.validation import check_int, check_range, check_types

__all__ = [
    "CNNRegistration", "CNNTrainConfig", "DEFAULT_WEIGHTS", "GridMapConfig", "TRAIN_COMMAND", "build_network",
    "grid_map", "load_weights", "pair_input", "train_cnn", "weights_record",
]

DEFAULT_WEIGHTS = Path(__file__).parent.parent / "data" / "registration_cnn.pt"
#: how the weights are made (``rhs_studies.train_registration``)
TRAIN_COMMAND = "python scripts/train_registration.py"


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
        check_range("gamma_r", self.gamma_r, 0.0, 1e6)
        check_int("channels", self.channels, 1, 256)
        check_int("hidden", self.hidden, 1, 4096)


def weights_record(path: str | Path) -> Path:
    """The record written beside a weights file (``registration_cnn.pt`` -> ``registration_cnn.json``)."""
    return Path(path).with_suffix(".json")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == Path(b).resolve()
    except OSError:
        return False


def _refuse_weights(path: Path, problem: str, shipped: bool) -> ValueError:
    fix = ("reinstall rhs-slam (in a source checkout: `git checkout -- slam/data`), or regenerate them with "
           f"`{TRAIN_COMMAND}`") if shipped else f"regenerate them with `{TRAIN_COMMAND} --out {path}`"
    return ValueError(f"CNN registration weights {path}: {problem}; {fix}")


def _record_for(path: Path, state: dict[str, Any], meta: dict[str, Any]) -> dict[str, Any]:
    """What :func:`weights_record` holds for a weights file: its sha256, grid and network sizes."""
    return {"file": path.name, "sha256": file_sha256(path), "grid": meta["grid"], "channels": meta["channels"],
            "hidden": meta["hidden"], "tensors": {k: list(v.shape) for k, v in state.items()},
            "made_by": TRAIN_COMMAND}


def _check_meta(meta: Any) -> GridMapConfig:
    """The grid map of a weights file's ``meta`` after checking its entries (ValueError with the reason)."""
    if not isinstance(meta, dict) or not {"grid", "scale", "channels", "hidden"} <= set(meta):
        raise ValueError("'meta' must hold grid, scale, channels and hidden")
    if not isinstance(meta["grid"], dict) or set(meta["grid"]) != {"cells", "cell_m"}:
        raise ValueError(f"meta grid must hold cells and cell_m, got {meta['grid']!r}")
    grid = GridMapConfig(**meta["grid"])
    scale = meta["scale"]
    if (not isinstance(scale, list) or len(scale) != 3
            or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in scale)):
        raise ValueError(f"meta scale must be 3 positive finite numbers, got {scale!r}")
    for name in ("channels", "hidden"):
        if not isinstance(meta[name], int) or not 1 <= meta[name] <= 4096:
            raise ValueError(f"meta {name} must be an integer in [1, 4096], got {meta[name]!r}")
    return grid


def load_weights(path: str | Path, shipped: bool = False) -> tuple[dict[str, Any], dict[str, Any], GridMapConfig]:
    """Read and verify a weights file (module docstring): its state dict, meta and grid map.

    Args:
        path: the ``.pt`` file (:func:`train_cnn` writes it).
        shipped: whether it is the shipped file, whose record (:func:`weights_record`) must exist and match.

    Returns:
        ``(state_dict, meta, grid)``.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: the file or its record is damaged or made for another network (names the file and the fix).
    """
    torch = _torch()
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"CNN registration weights not found at {path}; train them with {TRAIN_COMMAND}")
    if not path.is_file():
        raise _refuse_weights(path, "not a regular file", shipped)
    record_path = weights_record(path)
    record = None
    if record_path.is_file():
        try:
            record = json.loads(record_path.read_text())
        except (OSError, ValueError) as exc:
            raise _refuse_weights(path, f"its record {record_path} is unreadable ({exc})", shipped) from None
        if not isinstance(record, dict) or not isinstance(record.get("sha256"), str):
            raise _refuse_weights(path, f"its record {record_path} holds no sha256", shipped)
        if file_sha256(path) != record["sha256"]:
            raise _refuse_weights(path, f"the file's sha256 differs from the one in {record_path} (truncated, "
                                        f"replaced or edited)", shipped)
    elif shipped:
        raise _refuse_weights(path, f"its record {record_path} (the file's sha256) is missing", shipped)
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # (PytorchStreamReader, UnpicklingError, EOFError: any is a bad file)
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise _refuse_weights(path, f"not a readable weights file ({type(exc).__name__}: {message[:200]})",
                              shipped) from None
    if not isinstance(blob, dict) or not isinstance(blob.get("state_dict"), dict) or "meta" not in blob:
        raise _refuse_weights(path, "the file must hold a dict with 'state_dict' and 'meta'", shipped)
    try:
        grid = _check_meta(blob["meta"])
    except (TypeError, ValueError) as exc:
        raise _refuse_weights(path, f"bad meta ({exc})", shipped) from None
    meta, state = blob["meta"], blob["state_dict"]
    expect = {k: tuple(v.shape) for k, v in build_network(grid, meta["channels"], hidden=meta["hidden"])
              .state_dict().items()}
    got = {k: tuple(getattr(v, "shape", ())) for k, v in state.items()}
    if got != expect:
        wrong = sorted(k for k in set(got) | set(expect) if got.get(k) != expect.get(k))
        raise _refuse_weights(path, f"tensors {wrong} do not fit the network of its grid {meta['grid']} "
                                    f"(made for another grid map or network)", shipped)
    if not all(bool(torch.isfinite(v).all()) for v in state.values()):
        raise _refuse_weights(path, "non-finite weights", shipped)
    if record is not None:
        for key in ("grid", "channels", "hidden"):
            if key in record and record[key] != meta[key]:
                raise _refuse_weights(path, f"{key} {meta[key]!r} differs from {record[key]!r} in {record_path}",
                                      shipped)
    return state, meta, grid


class CNNRegistration:
    """Registration by the trained CNN; ``estimate(prev, cur, prior) -> (dx, dy, dheading)``.

    The network regresses ``target / scale`` where ``target`` is the residual
    motion after the prior; ``scale`` (3,) is stored with the weights.
    """

    def __init__(self, weights: str | Path | None = None, grid: GridMapConfig | None = None):
        torch = _torch()
        path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        state, meta, weights_grid = load_weights(path, shipped=weights is None or _same_file(path, DEFAULT_WEIGHTS))
        self.grid = grid or weights_grid
        if asdict(self.grid) != meta["grid"]:
            raise ValueError(f"{path}: weights were trained for grid {meta['grid']}, not {asdict(self.grid)}")
        self.scale = np.asarray(meta["scale"], dtype=float)
        self.meta = meta
        self.net = build_network(self.grid, meta["channels"], hidden=meta["hidden"])
        self.net.load_state_dict(state)
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
        out = Path(out)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
        torch.save({"state_dict": state, "meta": meta}, tmp)
        os.replace(tmp, out)
        record = weights_record(out)
        tmp_record = record.with_name(f".{record.name}.{os.getpid()}.tmp")
        tmp_record.write_text(json.dumps(_record_for(out, state, meta), indent=1, sort_keys=True) + "\n")
        os.replace(tmp_record, record)  # (meta must stay JSON-serialisable: the record holds its grid)
    return {"history": history, "scale": scale, "net": net}
