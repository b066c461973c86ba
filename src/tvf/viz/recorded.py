"""Labelled GIFs of recorded episodes (:func:`tvf.evaluate.recording.record_episode`).

Every frame is one observation the policy acted on. A text bar names the step, the action taken from it
(pick -> place in pixels and metres, the block's turn in degrees) and the progress (targets filled); the
last frame carries a success or failure badge. Below it, columns of colour over height: the real
observation (green border, the action marked on it), the imagined best path of a TVF decision (blue) and
the goal (grey); a legend at the bottom names the borders and marks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from tvf.evaluate.recording import RecordedEpisode, RecordedStep
from tvf.geometry import world_to_pixel, wrap_angle
from tvf.viz.images import HEIGHT_DISPLAY_MAX, height_to_rgb, save_gif
from tvf.viz.plan import imagined_views

SCALE = 2
"""Each image pixel is drawn as SCALE x SCALE."""
GAP = 6
BORDER = 3
FONT_SIZE = 15
LINE = FONT_SIZE + 5
REAL, IMAGINED, GOAL = (40, 170, 40), (40, 90, 220), (150, 150, 150)
PICK, PLACE = (255, 225, 0), (0, 230, 255)
SUCCESS, FAILURE = (30, 140, 60), (200, 40, 40)
WHITE, BLACK, BLANK = (255, 255, 255), (0, 0, 0), (235, 235, 235)


@lru_cache(maxsize=4)
def font(size: int = FONT_SIZE) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's built-in font at ``size`` pixels."""
    return ImageFont.load_default(size=size)


# ----------------------------------------------------------------------------------------------- text


def action_text(action: np.ndarray) -> str:
    """``pick (r, c) -> place (r, c) px = (x, y) -> (x, y) m, turn +90°`` for a ``(2, 4)`` action; the
    turn is the place yaw minus the pick yaw, in degrees."""
    a = np.asarray(action, dtype=np.float64)
    (pr, pc), (qr, qc) = world_to_pixel(a[0, :2]), world_to_pixel(a[1, :2])
    turn = math.degrees(float(wrap_angle(a[1, 3] - a[0, 3])))
    return (
        f"pick ({pr}, {pc}) -> place ({qr}, {qc}) px = ({a[0, 0]:.3f}, {a[0, 1]:.3f}) -> "
        f"({a[1, 0]:.3f}, {a[1, 1]:.3f}) m, turn {turn:+.0f}°"
    )


def progress_text(episode: RecordedEpisode, progress: float) -> str:
    """``progress 2/3 targets``."""
    return f"progress {episode.done(progress)}/{episode.n_targets} targets"


def badge_text(episode: RecordedEpisode, progress: float, steps: int) -> str:
    """The last frame's badge: ``SUCCESS: 3/3 targets in 3 steps`` or ``FAILURE: 2/3 targets ...``."""
    word = "SUCCESS" if episode.success else "FAILURE"
    return f"{word}: {episode.done(progress)}/{episode.n_targets} targets in {steps} steps"


def frame_lines(episode: RecordedEpisode, steps: list[RecordedStep], t: int) -> list[str]:
    """The text bar of frame ``t``: who and where, the action taken from this observation, the progress."""
    head = f"{episode.method} · {episode.task} · seed {episode.seed}"
    step = steps[t]
    n_actions = sum(s.action is not None for s in steps)
    if t == len(steps) - 1:
        return [f"{head} · end after {n_actions} steps", progress_text(episode, step.progress)]
    if step.action is None:
        action = "no action: the policy gave up"
    else:
        action = "action: " + action_text(step.action)
        if step.primitive not in (None, "ok"):
            action += f" (motion: {step.primitive})"
    return [
        f"{head} · step {t + 1} of at most {episode.horizon}",
        action,
        progress_text(episode, step.progress),
    ]


# ----------------------------------------------------------------------------------------------- images


def _enlarge(image: np.ndarray) -> np.ndarray:
    return image.repeat(SCALE, 0).repeat(SCALE, 1)


def _framed(image: np.ndarray, color: tuple[int, int, int]) -> np.ndarray:
    out = image.copy()
    out[:BORDER], out[-BORDER:], out[:, :BORDER], out[:, -BORDER:] = color, color, color, color
    return out


def view_column(color: np.ndarray, height: np.ndarray, border: tuple[int, int, int]) -> np.ndarray:
    """Colour above height, enlarged and framed in ``border``."""
    gap = np.full((GAP, color.shape[1] * SCALE, 3), 255, np.uint8)
    top, bottom = _framed(_enlarge(color), border), _framed(_enlarge(height_to_rgb(height)), border)
    return np.concatenate([top, gap, bottom], axis=0)


def mark_action(image: Image.Image, action: np.ndarray, origins: list[tuple[int, int]]) -> None:
    """Draw the pick (cross) and the place (circle with a tick for the block's turn), joined by a line,
    on each panel whose top-left corner is in ``origins``."""
    a = np.asarray(action, dtype=np.float64)
    (pr, pc), (qr, qc) = world_to_pixel(a[0, :2]), world_to_pixel(a[1, :2])
    turn = float(a[1, 3] - a[0, 3])  # image angle == world yaw in (col, row); rows grow downwards
    draw = ImageDraw.Draw(image)
    r = 3 * SCALE
    for x0, y0 in origins:
        p = (x0 + (pc + 0.5) * SCALE, y0 + (pr + 0.5) * SCALE)
        q = (x0 + (qc + 0.5) * SCALE, y0 + (qr + 0.5) * SCALE)
        draw.line([p, q], fill=WHITE, width=1)
        for color, w in ((BLACK, 5), (PICK, 3)):  # a dark outline keeps the cross visible on any block
            draw.line([(p[0] - r, p[1] - r), (p[0] + r, p[1] + r)], fill=color, width=w)
            draw.line([(p[0] - r, p[1] + r), (p[0] + r, p[1] - r)], fill=color, width=w)
        draw.ellipse([q[0] - r, q[1] - r, q[0] + r, q[1] + r], outline=PLACE, width=3)
        draw.line(
            [q, (q[0] + 2.5 * r * math.cos(turn), q[1] + 2.5 * r * math.sin(turn))], fill=PLACE, width=3
        )


def wrap(text: str, width: int) -> list[str]:
    """``text`` broken at spaces into lines no wider than ``width`` pixels (a longer word stays whole)."""
    lines: list[str] = []
    for word in text.split(" "):
        if lines and font().getlength(lines[-1] + " " + word) <= width:
            lines[-1] += " " + word
        else:
            lines.append(word)
    return lines


def text_bar(lines: list[str], width: int, n_lines: int) -> Image.Image:
    """A white bar ``width`` wide with room for ``n_lines`` lines of text."""
    bar = Image.new("RGB", (width, n_lines * LINE + 6), WHITE)
    draw = ImageDraw.Draw(bar)
    for i, line in enumerate(lines):
        draw.text((6, 4 + i * LINE), line, fill=BLACK, font=font())
    return bar


def badge(image: Image.Image, text: str, success: bool) -> None:
    """A filled badge with ``text`` in white, centred over the image."""
    draw = ImageDraw.Draw(image)
    big = font(2 * FONT_SIZE if image.width > 900 else FONT_SIZE + 3)
    left, top, right, bottom = draw.textbbox((0, 0), text, font=big)
    w, h = right - left + 40, bottom - top + 24
    x, y = (image.width - w) // 2, (image.height - h) // 2
    fill = SUCCESS if success else FAILURE
    draw.rounded_rectangle([x, y, x + w, y + h], radius=10, fill=fill, outline=WHITE, width=3)
    draw.text((x + 20 - left, y + 12 - top), text, fill=WHITE, font=big)


Icon = Callable[[Image.Image, int, int], None]


def _box(color: tuple[int, int, int]) -> Icon:
    return lambda image, x, y: ImageDraw.Draw(image).rectangle(
        [x, y + 2, x + 14, y + 16], outline=color, width=3
    )


def _cross(image: Image.Image, x: int, y: int) -> None:
    draw = ImageDraw.Draw(image)
    for color, w in ((BLACK, 5), (PICK, 3)):
        draw.line([(x + 1, y + 3), (x + 13, y + 15)], fill=color, width=w)
        draw.line([(x + 1, y + 15), (x + 13, y + 3)], fill=color, width=w)


def _circle(image: Image.Image, x: int, y: int) -> None:
    draw = ImageDraw.Draw(image)
    draw.ellipse([x + 1, y + 3, x + 13, y + 15], outline=PLACE, width=3)
    draw.line([(x + 7, y + 9), (x + 17, y + 9)], fill=PLACE, width=3)


def _ramp(image: Image.Image, x: int, y: int) -> None:
    ramp = height_to_rgb(np.linspace(0, HEIGHT_DISPLAY_MAX, 60)[None].repeat(14, 0))
    image.paste(Image.fromarray(ramp), (x, y + 2))


LEGEND_ICON = {"box": 20, "mark": 22, "ramp": 66}


def legend_items(imagined: bool) -> list[tuple[str, Icon, str]]:
    """The legend's entries: (icon kind, icon drawer, text)."""
    items = [("box", _box(REAL), "real observation")]
    if imagined:
        items.append(("box", _box(IMAGINED), "imagined by the VF along the planner's best path"))
    items += [
        ("box", _box(GOAL), "goal"),
        ("mark", _cross, "pick"),
        ("mark", _circle, "place, tick: the block's turn (the action taken from this observation)"),
        ("ramp", _ramp, f"height 0-{100 * HEIGHT_DISPLAY_MAX:.0f} cm (bottom row; top row: colour)"),
    ]
    return items


def legend(width: int, imagined: bool) -> Image.Image:
    """The legend strip ``width`` wide: the borders, the action marks, the height scale (entries flow
    onto new lines when the frame is narrow)."""
    placed, x, row = [], 6, 0
    for kind, icon, text in legend_items(imagined):
        w = LEGEND_ICON[kind] + int(font().getlength(text)) + 22
        if x > 6 and x + w > width:
            x, row = 6, row + 1
        placed.append((x, row, kind, icon, text))
        x += w
    bar = Image.new("RGB", (width, (row + 1) * LINE + 8), WHITE)
    draw = ImageDraw.Draw(bar)
    for x, r, kind, icon, text in placed:
        y = 4 + r * LINE
        icon(bar, x, y)
        draw.text((x + LEGEND_ICON[kind], y + 1), text, fill=BLACK, font=font())
    return bar


def path_columns(step: RecordedStep, slots: int, blank: np.ndarray) -> list[np.ndarray]:
    """The imagined best path of the step's plan as ``slots`` columns (``blank`` where it is shorter)."""
    out: list[np.ndarray] = []
    plan = step.plan
    if plan is not None and plan.images is not None:
        colors, heights = imagined_views(plan.images[[n.index for n in plan.path]])
        out = [view_column(c, h, IMAGINED) for c, h in zip(colors, heights, strict=True)]
    return out + [blank] * (slots - len(out))


def _with_headers(columns: list[np.ndarray], names: list[str]) -> np.ndarray:
    """Columns side by side with a name over each."""
    spacer = np.full((columns[0].shape[0], GAP, 3), 255, np.uint8)
    parts = [p for c in columns for p in (c, spacer)][:-1]
    body = np.concatenate(parts, axis=1)
    head = Image.new("RGB", (body.shape[1], LINE + 2), WHITE)
    draw = ImageDraw.Draw(head)
    for i, name in enumerate(names):
        draw.text((i * (columns[0].shape[1] + GAP) + 4, 2), name, fill=BLACK, font=font())
    return np.concatenate([np.asarray(head), body], axis=0)


def path_slots(steps: list[RecordedStep]) -> int:
    """The longest imagined path of the episode (0 when no step kept a plan with images)."""
    plans = [s.plan for s in steps if s.plan is not None and s.plan.images is not None]
    return max((len(p.path) for p in plans), default=0)


def step_body(step: RecordedStep, slots: int) -> Image.Image:
    """The step's columns under their names: real (the action marked on it), ``slots`` imagined, goal."""
    real = view_column(step.obs["color"], step.obs["height"], REAL)
    blank = np.full_like(real, BLANK)
    columns = [
        real,
        *path_columns(step, slots, blank),
        view_column(step.goal["color"], step.goal["height"], GOAL),
    ]
    names = ["real (now)", *(f"imagined +{i + 1}" for i in range(slots)), "goal"]
    body = Image.fromarray(_with_headers(columns, names))
    if step.action is not None:
        top, rows = LINE + 2, step.obs["color"].shape[0] * SCALE
        mark_action(body, step.action, [(0, top), (0, top + rows + GAP)])
    return body


def stacked(bar: Image.Image, body: Image.Image, strip: Image.Image) -> np.ndarray:
    """Text bar, body and legend one above the other."""
    frame = Image.new("RGB", (body.width, bar.height + body.height + strip.height), WHITE)
    frame.paste(bar, (0, 0))
    frame.paste(body, (0, bar.height))
    frame.paste(strip, (0, bar.height + body.height))
    return np.asarray(frame)


def decision_picture(step: RecordedStep, lines: list[str]) -> np.ndarray:
    """One decision (``tvf plan``): the ``lines`` of text, the observation with the action marked, the
    imagined best path when the step's plan kept its images, the goal, and the legend."""
    slots = path_slots([step])
    body = step_body(step, slots)
    text = [w for line in lines for w in wrap(line, body.width - 12)]
    return stacked(text_bar(text, body.width, len(text)), body, legend(body.width, slots > 0))


def frame_body(episode: RecordedEpisode, steps: list[RecordedStep], t: int, slots: int) -> Image.Image:
    """The columns of frame ``t`` under their names, the action marked on the real one, the badge last."""
    step = steps[t]
    body = step_body(step, slots)
    if t == len(steps) - 1:
        n_actions = sum(s.action is not None for s in steps)
        badge(body, badge_text(episode, step.progress, n_actions), episode.success)
    return body


def episode_frames(episode: RecordedEpisode, steps: list[RecordedStep]) -> list[np.ndarray]:
    """One labelled frame per recorded step (the final state last, with the badge); all the same size."""
    slots = path_slots(steps)
    bodies = [frame_body(episode, steps, t, slots) for t in range(len(steps))]
    width = bodies[0].width
    texts = [
        [w for line in frame_lines(episode, steps, t) for w in wrap(line, width - 12)]
        for t in range(len(steps))
    ]
    n_lines = max(len(t) for t in texts)
    strip = legend(width, slots > 0)
    frames = []
    for body, lines in zip(bodies, texts, strict=True):
        frames.append(stacked(text_bar(lines, width, n_lines), body, strip))
    return frames


def episode_gif(path: Path, episode: RecordedEpisode, steps: list[RecordedStep], fps: float = 1.0) -> Path:
    """Write the labelled GIF of a recorded episode; the last frame (the badge) shows twice as long."""
    save_gif(path, episode_frames(episode, steps), fps, hold_last=2.0)
    return Path(path)
