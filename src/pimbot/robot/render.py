"""Videos of a physics episode: MuJoCo's offscreen renderer, or a matplotlib top-down fallback.

MuJoCo needs an OpenGL backend: `MUJOCO_GL=egl` (Mesa's EGL works without a
display or a GPU) or `MUJOCO_GL=osmesa` (Debian's libosmesa6). Both must be
chosen before `mujoco` is first imported. `opengl_backend()` finds one that
works in a subprocess (`pimbot.robot.gl`); without one, `render_episode` falls back to the 2-D
matplotlib animation of the same trajectory, which always works.
Output: GIF through Pillow, MP4 through ffmpeg when it is installed.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from pimbot.atomic_files import staged
from pimbot.robot.episode import GATE_OPEN_FRACTION, EpisodeResult
from pimbot.robot.world import (
    DOOR_GAP,
    GATE_TRAVEL,
    ROBOT_RADIUS,
    WALL_THICKNESS,
    ZONE_COLOURS,
    ZONE_NAMES,
)

FORMATS = (".gif", ".mp4")
ROBOT_COLOURS = ("#4363d8", "#3cb44b", "#f58231", "#911eb4", "#42d4f4", "#469990")
"""Honest robots; none is red, which marks the adversary."""
ADVERSARY_COLOUR = "#d00000"
ZONE_ROLES = {
    "lever": "lever zone: holds the door open",
    "start": "start zone",
    "door": "door zone: exit, +10 when open",
}
"""What each zone of `world.ZONE_NAMES` is, for the legend of every frame."""
OPEN_COLOUR, CLOSED_COLOUR = "#1b7a2e", "#b00020"
STRIP = 84
"""Pixels of the legend and status strip below a MuJoCo frame."""


def check_output_path(out: str | Path) -> Path:
    """The output path, if its suffix is a supported video format (else InvalidParameter)."""
    from pimbot.envs.core import InvalidParameter

    path = Path(out)
    if path.suffix.lower() not in FORMATS:
        raise InvalidParameter(f"out: must end in {' or '.join(FORMATS)}, got {path.name!r}")
    if path.suffix.lower() == ".mp4" and shutil.which("ffmpeg") is None:
        raise InvalidParameter("out: .mp4 needs ffmpeg, which is not installed; use .gif")
    return path


def adversary_of(config: dict) -> int | None:
    """The adversary's agent index of a run's config.json: its attack parameter `adversary`
    (agent 0 where the attack has none); None for a clean run."""
    identity = config.get("identity", {})
    if not identity.get("attack"):
        return None
    return int(identity.get("attack_params", {}).get("adversary", 0))


def run_adversary(run_dir: str | Path) -> int | None:
    """`adversary_of` the config.json of a run directory."""
    from pimbot.training import store

    return adversary_of(store.read_json(Path(run_dir) / store.CONFIG))


def frame_indices(result: EpisodeResult, fps: int, speedup: float) -> np.ndarray:
    """Trace ticks to show: one frame per `speedup / fps` simulated seconds."""
    times = result.trace["time"]
    wanted = np.arange(times[0], times[-1] + 1e-9, speedup / fps)
    return np.unique(np.clip(np.searchsorted(times, wanted), 0, len(times) - 1))


def decision_at(result: EpisodeResult, k: int) -> int:
    """The decision step (1-based) trace tick `k` belongs to: decision t covers the
    simulated time from the end of decision t − 1 to the end of its settling."""
    ends = np.cumsum(result.decision_seconds)  # the episode starts at simulated time 0
    if ends.size == 0:
        return 0
    return int(min(np.searchsorted(ends, result.trace["time"][k] - 1e-9) + 1, ends.size))


def robot_colour(i: int, adversary: int | None) -> str:
    return ADVERSARY_COLOUR if i == adversary else ROBOT_COLOURS[i % len(ROBOT_COLOURS)]


def robot_label(result: EpisodeResult, i: int, decision: int, adversary: int | None) -> str:
    """ "1 → door", "0 adversary → start": the robot id and the zone it was sent to."""
    name = f"{i} adversary" if i == adversary else str(i)
    if 1 <= decision <= result.steps:
        name += f" → {ZONE_NAMES[int(result.actions[decision - 1][i])]}"
    return name


def status(result: EpisodeResult, k: int) -> tuple[str, bool]:
    """(the status line of tick `k`, whether the door is open)."""
    opening = float(result.trace["gate"][k])
    is_open = opening >= GATE_OPEN_FRACTION
    state = "OPEN" if is_open else "CLOSED"
    time = result.trace["time"][k]
    line = (
        f"decision {decision_at(result, k)} of {result.steps}   t = {time:5.1f} s   "
        f"door {state} (gate {max(0, round(opening * 100))} % open)"
    )
    return line, is_open


def _hex_rgb(colour) -> tuple[int, int, int]:
    from matplotlib.colors import to_rgba

    r, g, b, a = to_rgba(colour)
    # Zone colours are translucent: shown as they look over the white floor.
    return tuple(int(round(255 * (a * c + (1 - a)))) for c in (r, g, b))  # type: ignore[return-value]


def mujoco_frames(
    result: EpisodeResult,
    indices: np.ndarray,
    size=(640, 480),
    adversary: int | None = None,
    title: str = "",
    annotate: bool = True,
) -> list[np.ndarray]:
    """Top-down RGB frames [H, W, 3] rendered by MuJoCo from the recorded trace.

    With `annotate`, the scene takes the top `H - STRIP` pixels and a strip below it
    holds the zone legend, the decision counter and the door state; every robot gets a
    ring in its colour and its id (the adversary red, labelled). Needs a working MUJOCO_GL
    backend (set before mujoco was imported).
    """
    import mujoco

    width, height = size
    scene_h = height - STRIP if annotate else height
    world = result.world
    model, data = world.model, mujoco.MjData(world.model)
    layout = world.layout
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (0.0, 0.0, 0.0)
    camera.azimuth, camera.elevation = 90.0, -90.0
    fovy = math.radians(model.vis.global_.fovy)
    span = max(layout.height + 0.4, (layout.width + 0.4) * scene_h / width)
    camera.distance = 0.5 * span / math.tan(fovy / 2)
    frames = []
    renderer = mujoco.Renderer(model, scene_h, width)
    try:
        for k in indices:
            for i, (x, y, theta) in enumerate(result.trace["poses"][k]):
                a = world.base_qpos[i]
                data.qpos[a : a + 7] = (x, y, 0, math.cos(theta / 2), 0, 0, math.sin(theta / 2))
            data.qpos[world.gate_qpos] = result.trace["gate"][k] * world.gate_open_target
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera)
            frame = renderer.render().copy()
            if annotate:
                frame = _annotate(frame, result, int(k), height, scene_h / span, adversary, title)
            frames.append(frame)
    finally:
        renderer.close()
    return frames


def _font(size: int, weight: str = "normal"):
    from matplotlib import font_manager
    from PIL import ImageFont

    props = font_manager.FontProperties(family="DejaVu Sans", weight=weight)
    return ImageFont.truetype(font_manager.findfont(props), size)


def _annotate(frame, result, k, height, scale, adversary, title) -> np.ndarray:
    """The MuJoCo scene with rings and ids on the robots, over a legend and status strip."""
    from PIL import Image, ImageDraw

    scene_h, width = frame.shape[:2]
    canvas = Image.new("RGB", (width, height), "white")
    canvas.paste(Image.fromarray(frame), (0, 0))
    draw = ImageDraw.Draw(canvas)
    small, bold = _font(11), _font(12, "bold")
    decision = decision_at(result, k)

    def pixel(x: float, y: float) -> tuple[float, float]:
        return width / 2 + x * scale, scene_h / 2 - y * scale

    layout = result.world.layout
    for name, (cx, cy) in zip(ZONE_NAMES, layout.zone_centres, strict=True):
        draw.text(pixel(cx, cy + layout.zone_half), name, fill="black", font=small, anchor="md")
    radius = ROBOT_RADIUS * scale
    for i, (x, y, _) in enumerate(result.trace["poses"][k]):
        px, py = pixel(x, y)
        colour = robot_colour(i, adversary)
        ring = radius + (6 if i == adversary else 3)
        draw.ellipse((px - ring, py - ring, px + ring, py + ring), outline=colour, width=4)
        if i == adversary:
            draw.ellipse((px - ring - 3, py - ring - 3, px + ring + 3, py + ring + 3),
                         outline="black", width=1)  # fmt: skip
        label = robot_label(result, i, decision, adversary)
        # Above the robot for even ids, below for odd: neighbours in a zone do not overlap.
        anchor, ty = ("md", py - ring - 4) if i % 2 == 0 else ("ma", py + ring + 4)
        box = draw.textbbox((px, ty), label, font=bold, anchor=anchor)
        draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill="white")
        draw.text((px, ty), label, fill=colour, font=bold, anchor=anchor)
    line, is_open = status(result, k)
    top = scene_h + 6
    if title:
        draw.text((8, top), title, fill="black", font=small)
        top += 16
    draw.text((8, top), line, fill=OPEN_COLOUR if is_open else CLOSED_COLOUR, font=bold)
    top += 20
    x = 8
    for name, colour in zip(ZONE_NAMES, ZONE_COLOURS, strict=True):
        draw.rectangle((x, top + 1, x + 12, top + 13), fill=_hex_rgb(colour), outline="black")
        text = ZONE_ROLES.get(name, name)
        draw.text((x + 16, top), text, fill="black", font=small)
        x += 16 + draw.textlength(text, font=small) + 14
        if x > width - 150:
            x, top = 8, top + 16
    if adversary is not None:
        draw.text((x, top), f"red ring: robot {adversary}, the adversary", fill=ADVERSARY_COLOUR,
                  font=small)  # fmt: skip
    return np.asarray(canvas)


def matplotlib_frames(
    result: EpisodeResult,
    indices: np.ndarray,
    size=(640, 480),
    title: str = "",
    adversary: int | None = None,
) -> list[np.ndarray]:
    """Top-down RGB frames drawn with matplotlib (Agg) from the recorded trace: zones with
    a legend of what each is, robots with their ids and the zone each was sent to (the
    adversary, where there is one, red and labelled), the door state and the decision
    counter."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dpi = 100
    fig = plt.figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi)
    ax = fig.add_axes((0.02, 0.16, 0.96, 0.74))
    handles = _legend_handles(result.world.num_robots, adversary)
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=7, frameon=False)
    frames = []
    for k in indices:
        ax.clear()
        _draw_room(ax, result.world.layout)
        line, is_open = status(result, k)
        _draw_door(ax, result.world.layout, result.trace["gate"][k], is_open)
        _draw_robots(ax, result, k, adversary)
        _draw_headline(fig, title, line, OPEN_COLOUR if is_open else CLOSED_COLOUR)
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    return frames


def _legend_handles(num_robots: int, adversary: int | None) -> list:
    """The legend of every matplotlib frame: each zone's role, the gate, each robot."""
    import matplotlib.patches as patches
    from matplotlib.lines import Line2D

    handles = [
        patches.Patch(color=colour, label=ZONE_ROLES.get(name, name))
        for name, colour in zip(ZONE_NAMES, ZONE_COLOURS, strict=True)
    ]
    handles.append(patches.Patch(color="#8c4d26", label="gate (slides open)"))
    for i in range(num_robots):
        label = f"robot {i}" + (" (adversary)" if i == adversary else "")
        handles.append(
            Line2D([], [], ls="", marker="o", ms=8, mfc=robot_colour(i, adversary),
                   mec="black" if i == adversary else "none", mew=2, label=label)
        )  # fmt: skip
    return handles


def _draw_room(ax, layout) -> None:
    """The room's walls and its zones with their names, on a cleared axes."""
    import matplotlib.patches as patches

    w, h = layout.width, layout.height
    ax.set_xlim(-w / 2 - 0.2, w / 2 + 0.2)
    ax.set_ylim(-h / 2 - 0.2, h / 2 + 0.2)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.add_patch(patches.Rectangle((-w / 2, -h / 2), w, h, fill=False, lw=3, ec="#8c8270"))
    for name, (cx, cy), colour in zip(ZONE_NAMES, layout.zone_centres, ZONE_COLOURS, strict=True):
        half = layout.zone_half
        ax.add_patch(patches.Rectangle((cx - half, cy - half), 2 * half, 2 * half, color=colour))
        ax.text(cx, cy + half + 0.05, name, ha="center", fontsize=9)


def _draw_door(ax, layout, opening, is_open: bool) -> None:
    """The doorway, the gate slid along the wall by its `opening` (a fraction), and the
    door's state."""
    import matplotlib.patches as patches

    w = layout.width
    ax.plot(
        [w / 2, w / 2],
        [layout.door_y - DOOR_GAP / 2, layout.door_y + DOOR_GAP / 2],
        color="white",
        lw=4,
    )
    shift = opening * GATE_TRAVEL * layout.gate_direction
    ax.add_patch(
        patches.Rectangle(
            (w / 2 - WALL_THICKNESS / 4, layout.door_y - DOOR_GAP / 2 + shift),
            WALL_THICKNESS / 2 + 0.02,
            DOOR_GAP,
            color="#8c4d26",
        )
    )
    ax.text(
        w / 2 + 0.1, layout.door_y, "open" if is_open else "closed",
        color=OPEN_COLOUR if is_open else CLOSED_COLOUR,
        ha="center", va="center", fontsize=8, fontweight="bold", rotation=90,
    )  # fmt: skip


def _draw_robots(ax, result: EpisodeResult, k: int, adversary: int | None) -> None:
    """Each robot at trace tick `k`: its path so far, its body and heading, its id, and
    its label (the zone it was sent to)."""
    import matplotlib.patches as patches

    decision = decision_at(result, k)
    for i, (x, y, theta) in enumerate(result.trace["poses"][k]):
        colour = robot_colour(i, adversary)
        adv = i == adversary
        path = result.trace["poses"][0 : k + 1, i]
        ax.plot(path[:, 0], path[:, 1], color=colour, lw=1, alpha=0.6)
        ax.add_patch(
            patches.Circle(
                (x, y), ROBOT_RADIUS, fc=colour, alpha=0.95,
                ec="black" if adv else "white", lw=2.5 if adv else 1,
            )
        )  # fmt: skip
        ax.plot([x, x + 0.12 * math.cos(theta)], [y, y + 0.12 * math.sin(theta)], "k-", lw=2)
        ax.text(x, y, str(i), ha="center", va="center", color="white", fontsize=8)
        label = robot_label(result, i, decision, adversary)
        up = 1 if i % 2 == 0 else -1  # neighbours in a zone: labels above and below
        ax.text(
            x, y + up * (ROBOT_RADIUS + 0.04), label, color=colour, fontsize=8,
            ha="center", va="bottom" if up > 0 else "top",
            fontweight="bold" if adv else "normal",
            bbox={"fc": "white", "ec": "none", "alpha": 0.75, "pad": 1},
        )  # fmt: skip


def _draw_headline(fig, title: str, line: str, colour: str) -> None:
    """The figure's title and status line (replacing the previous frame's)."""
    fig.texts.clear()
    if title:
        fig.text(0.5, 0.965, title, ha="center", va="center", fontsize=9)
    fig.text(0.5, 0.925, line, ha="center", va="center", fontsize=9, color=colour,
             fontweight="bold")  # fmt: skip


def write_video(frames: list[np.ndarray], out: Path, fps: int) -> None:
    """GIF via Pillow, MP4 via ffmpeg (H.264, yuv420p)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with staged(out) as tmp:
        if out.suffix.lower() == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            images[0].save(
                tmp, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0
            )
        else:
            height, width = frames[0].shape[:2]
            command = [
                "ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
                "-s", f"{width}x{height}", "-r", str(fps), "-i", "-", "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-f", "mp4", str(tmp),
            ]  # fmt: skip
            subprocess.run(command, input=b"".join(f.tobytes() for f in frames), check=True)


def write_png(frame: np.ndarray, out: Path) -> None:
    from PIL import Image

    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(frame).save(out)


def render_episode(
    result: EpisodeResult,
    out: str | Path,
    renderer: str = "auto",
    fps: int = 10,
    speedup: float = 4.0,
    title: str = "",
    adversary: int | None = None,
) -> str:
    """Writes a top-down video of `result`; returns the renderer used ("mujoco" or
    "matplotlib").

    Args:
        renderer: "mujoco", "matplotlib", or "auto" (MuJoCo when OpenGL works).
        speedup: simulated seconds per second of video.
        adversary: the attacked run's adversary index (`run_adversary`), marked on every
            frame; None for a clean run.
    """
    path = check_output_path(out)
    indices = frame_indices(result, fps, speedup)
    if renderer == "auto":
        renderer = "mujoco" if os.environ.get("MUJOCO_GL") else "matplotlib"
    if renderer == "mujoco":
        frames = mujoco_frames(result, indices, adversary=adversary, title=title)
    else:
        frames = matplotlib_frames(result, indices, title=title, adversary=adversary)
    write_video(frames, path, fps)
    return renderer
