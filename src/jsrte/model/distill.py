"""Distillation: a cheaper decoder taught to reproduce a trained model's SDF over its latent space.

The student takes the same inputs as the teacher (a point and a latent code of the same size)
and learns the teacher's output, so it keeps the teacher's codes, its training codes' statistics
and its class sizes: a fit with the student lands in the same latent space as one with the
teacher. Each step draws codes around the teacher's training codes (the codes themselves, mixes
of two, and draws from their Gaussian), points near each code's surface (found by the teacher
among uniform candidates, then jittered as DeepSDF samples its training data) and uniform points,
and minimizes the clamped L1 between the two networks' outputs.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import torch

from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.config import cosine_factor
from jsrte.model.decoder import Decoder, DecoderConfig
from jsrte.model.train import clamped_l1


@dataclass(frozen=True)
class DistillSettings:
    """How a student decoder is taught.

    ``steps`` Adam steps on ``codes_per_step`` codes x ``points_per_code`` points; the learning
    rate follows a cosine from ``lr`` to ``final_lr_fraction`` of it over the steps, or over
    ``max_seconds`` of wall time when that comes first. Of each code's points, ``near_fraction``
    lie near its surface: those of ``candidates_per_code`` uniform candidates closest to the
    teacher's zero level set, moved onto it by Newton steps, each jittered by N(0, 0.025²) and
    N(0, 0.0025²); the rest are uniform in the cube of half-side ``box`` (canonical units).
    """

    steps: int = 20000
    codes_per_step: int = 64
    points_per_code: int = 4096
    candidates_per_code: int = 8192
    near_fraction: float = 0.75
    box: float = 1.1
    lr: float = 1e-3
    final_lr_fraction: float = 0.05
    clamp: float = 0.1
    max_seconds: float | None = None
    seed: int = 0

    def progress(self, step: int, elapsed: float) -> float:
        """The schedule's progress in [0, 1]: by steps, or by seconds when that is further."""
        by_steps = step / self.steps
        by_time = elapsed / self.max_seconds if self.max_seconds else 0.0
        return min(max(by_steps, by_time), 1.0)

    def lr_at(self, progress: float) -> float:
        """The learning rate at ``progress`` (:meth:`progress`)."""
        return self.lr * cosine_factor(progress, self.final_lr_fraction)


def draw_codes(codes: torch.Tensor, n: int, generator: torch.Generator) -> torch.Tensor:
    """``n`` codes (n, d) around the training ``codes`` (m, d): a third of them training codes, a
    third mixes of two at a uniform weight, a third Gaussian draws (their mean and covariance)
    scaled by a uniform factor in [0, 1.5] (the mean code among them)."""
    m, d = codes.shape
    third = n // 3
    pick = codes[torch.randint(m, (n - 2 * third,), generator=generator)]
    a, b = (codes[torch.randint(m, (third,), generator=generator)] for _ in range(2))
    w = torch.rand(third, 1, generator=generator)
    mixed = a * (1 - w) + b * w
    mean = codes.mean(0)
    cov = torch.cov(codes.T) + 1e-8 * torch.eye(d)
    chol = torch.linalg.cholesky(cov)
    scale = 1.5 * torch.rand(third, 1, generator=generator)
    gauss = mean + scale * (torch.randn(third, d, generator=generator) @ chol.T)
    return torch.cat([pick, mixed, gauss])


@torch.no_grad()
def draw_points(teacher: Decoder, codes: torch.Tensor, settings: DistillSettings,
                generator: torch.Generator) -> torch.Tensor:
    """Points (n, p, 3) for codes (n, d) on the teacher's device (``generator`` there too): near
    each code's surface and uniform (``DistillSettings``)."""
    device = codes.device
    n, p = codes.shape[0], settings.points_per_code
    n_near = int(round(p * settings.near_fraction)) // 2 * 2
    k = settings.candidates_per_code

    def uniform(count: int) -> torch.Tensor:
        return (torch.rand(n, count, 3, generator=generator, device=device) * 2 - 1) * settings.box

    candidates = uniform(k)
    sdf = teacher(candidates.reshape(-1, 3), codes.repeat_interleave(k, 0)).reshape(n, k)
    nearest = sdf.abs().topk(n_near // 2, dim=1, largest=False).indices
    surface = torch.gather(candidates, 1, nearest[..., None].expand(-1, -1, 3))
    surface = project_to_surface(teacher, surface, codes)
    sigma = torch.tensor([0.025, 0.0025], device=device).repeat_interleave(n_near // 2)[None, :, None]
    near = surface.repeat(1, 2, 1) + sigma * torch.randn(n, n_near, 3, generator=generator, device=device)
    return torch.cat([near, uniform(p - n_near)], dim=1)


def project_to_surface(decoder: Decoder, points: torch.Tensor, codes: torch.Tensor,
                       iterations: int = 2, max_step: float = 0.1) -> torch.Tensor:
    """Points (n, q, 3) moved onto the zero level set of codes (n, d) by Newton steps along the
    SDF's gradient, x - f(x) ∇f / |∇f|², each at most ``max_step`` long (canonical units)."""
    n, q, _ = points.shape
    per_point = codes.repeat_interleave(q, 0)
    flat = points.reshape(-1, 3)
    for _ in range(iterations):
        with torch.enable_grad():
            x = flat.detach().requires_grad_(True)
            sdf = decoder(x, per_point)
            (grad,) = torch.autograd.grad(sdf.sum(), x)
        step = sdf.detach()[:, None] * grad / grad.square().sum(1, keepdim=True).clamp_min(1e-6)
        length = step.norm(dim=1, keepdim=True)
        flat = flat - step * (max_step / length.clamp_min(max_step))
    return flat.reshape(n, q, 3)


def distill(teacher: DeepSdfModel, config: DecoderConfig, settings: DistillSettings, *,
            device: torch.device | str = "cpu", name: str | None = None, progress: bool = True,
            log: list[dict[str, float]] | None = None) -> DeepSdfModel:
    """A student with architecture ``config`` taught the teacher's SDF (``DistillSettings``);
    it carries the teacher's training codes and description. ``log`` (if given) receives a row
    every 100 steps: step, seconds, lr, loss."""
    from tqdm import tqdm

    if config.latent_size != teacher.latent_size:
        raise ValueError(f"the student's latent size {config.latent_size} is not the teacher's {teacher.latent_size}")
    torch.manual_seed(settings.seed)
    device = torch.device(device)
    generator = torch.Generator().manual_seed(settings.seed)
    point_generator = torch.Generator(device=device).manual_seed(settings.seed)
    teacher_net = Decoder(teacher.decoder.config)
    teacher_net.load_state_dict(teacher.decoder.state_dict())
    teacher_net = teacher_net.fold_weight_norm().eval().to(device)
    for param in teacher_net.parameters():
        param.requires_grad_(False)
    student = Decoder(config).to(device).train()
    optimizer = torch.optim.Adam(student.parameters(), lr=settings.lr)
    codes = teacher.codes.detach().float().cpu()
    start, step, loss_value = time.perf_counter(), 0, float("nan")
    bar = tqdm(total=settings.steps, desc="distilling", disable=not progress)
    while (done := settings.progress(step, time.perf_counter() - start)) < 1.0:
        lr = settings.lr_at(done)
        for group in optimizer.param_groups:
            group["lr"] = lr
        batch_codes = draw_codes(codes, settings.codes_per_step, generator).to(device)
        points = draw_points(teacher_net, batch_codes, settings, point_generator).reshape(-1, 3)
        per_point = batch_codes.repeat_interleave(settings.points_per_code, 0)
        with torch.no_grad():
            target = teacher_net(points, per_point)
        loss = clamped_l1(student(points, per_point), target, settings.clamp)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        bar.update(1)
        if step % 100 == 0:
            loss_value = float(loss.detach())
            if log is not None:
                log.append({"step": step, "seconds": round(time.perf_counter() - start, 1), "lr": lr,
                            "loss": loss_value})
    bar.close()
    student = student.cpu().eval()
    meta = {key: value for key, value in teacher.meta.items()
            if key not in ("training", "metrics", "sha256", "path")}
    meta.update(name=name or f"{teacher.name}-{_arch_name(config)}", arch=_arch_name(config),
                distilled_from={"name": teacher.name, "sha256": teacher.meta.get("sha256")},
                distillation={**asdict(settings), "steps_done": step,
                              "seconds": round(time.perf_counter() - start, 1), "device": str(device),
                              "final_loss": loss_value})
    return DeepSdfModel(student, teacher.codes.detach().clone(), meta)


def _arch_name(config: DecoderConfig) -> str:
    from jsrte.model.config import ARCHITECTURES

    return next((name for name, known in ARCHITECTURES.items() if known == config),
                f"{config.depth}x{config.hidden}")


@torch.no_grad()
def student_error(student: DeepSdfModel, teacher: DeepSdfModel, settings: DistillSettings, *,
                  n_codes: int = 64, seed: int = 1, device: torch.device | str = "cpu") -> dict[str, float]:
    """The mean absolute difference of the two networks' clamped outputs on fresh draws (codes and
    points as in training, another seed): over all points and over those within 0.01 of the
    teacher's surface. Both decoders are moved to ``device``."""
    device = torch.device(device)
    generator = torch.Generator().manual_seed(seed)
    teacher_net, student_net = teacher.decoder.to(device).eval(), student.decoder.to(device).eval()
    codes = draw_codes(teacher.codes.float().cpu(), n_codes, generator).to(device)
    points = draw_points(teacher_net, codes, settings, torch.Generator(device=device).manual_seed(seed))
    points = points.reshape(-1, 3)
    per_point = codes.repeat_interleave(settings.points_per_code, 0)
    t = teacher_net(points, per_point).clamp(-settings.clamp, settings.clamp)
    s = student_net(points, per_point).clamp(-settings.clamp, settings.clamp)
    near = t.abs() < 0.01
    return {"mean_abs": float((s - t).abs().mean()), "near_surface_mean_abs": float((s - t)[near].abs().mean())}
