"""report/animate.py -- one episode of a policy on a design, filmed from the side as a GIF (or MP4).

  1. `film`: play one episode and keep a side view every few control steps (PyBullet's CPU renderer)
  2. `outcome`: what the episode did to the curriculum level (cleared, held, fell back)
  3. `panel_frames` and `save_animation`: caption each frame, lay films side by side, write GIF or MP4

The camera follows the pelvis from the side, as report/strip.py's motion strip (paper Fig. 1) does, from farther
away (CAMERA_Y). The episode is the one ballu.score plays at that level (same env settings, reset seed 0), so a
film's final x is that episode's final x (test_use_watch_plays_the_episode_J_plays). The command line:
experiments/use.py (`python run_all.py watch ...`).

    from report.animate import film, panel_frames, save_animation
    f = film(policy, "obstacle", design_full, level=28, cfg=cfg)
    save_animation("anim.gif", panel_frames([(f, ["e2e MLP", "gcr 0.88 spcf 0.008"])], "obstacle", 28), fps=10)
"""
from __future__ import annotations

import functools
import shutil
import subprocess

import numpy as np

from ballu import BalluEnv, level_score, task_geometry

WIDTH, HEIGHT = 320, 240   # [ours] a panel's picture: small, so a 100-frame GIF of two panels stays ~1-2 MB
HEADER = 62                # pixels of caption above the picture (4 lines)
# [ours] the camera follows the pelvis from the side as report/strip.py's, but from 15 m (strip: 3.2 m, inside
# the terrain's 10 m width, so the box seems to run at the viewer) with a narrow lens: the box reads as a box
CAMERA_Y, FOV = -15.0, 11.0
HOLD_S = 2.0               # [ours] the last frame is held this long, so the outcome can be read


def film(policy, task: str, design, level: int, cfg, every: int = 4, max_steps: int | None = None,
         size=(WIDTH, HEIGHT)) -> dict:
    """Play one episode of `policy` on one full design (l_f, l_t, gcr, spcf) at `level` and render a side view
    every `every` control steps, plus the last state before the episode ends. `cfg`: the env settings the policy
    is scored with (codesign.policies.score_policy's), so the episode is the one J plays at that level. `max_steps` cuts it
    short (tests). Returns the frames (RGB arrays), their times (s) and pelvis x (m), the final x (None when cut
    short) and whether the episode blew up (ballu's safety limits)."""
    env = BalluEnv(1, cfg, curriculum=False)
    try:
        obs, _ = env.reset(seed=0, options={"designs": design, "levels": level})   # seed 0: as ballu.score
        p, body, (w, h) = env.client(0), env.bodies[0], size
        proj = p.computeProjectionMatrixFOV(FOV, w / h, 0.1, 40)
        T = cfg.episode_steps if max_steps is None else min(max_steps, cfg.episode_steps)
        out = {"frames": [], "t": [], "x": [], "final_x": None, "blowup": False}
        for t in range(T):
            x = p.getBasePositionAndOrientation(body)[0][0]
            if t % every == 0 or t == T - 1:   # the camera beside the pelvis (CAMERA_Y)
                view = p.computeViewMatrix([x, CAMERA_Y, 1.0], [x, 0, 0.8], [0, 0, 1])
                img = p.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER, lightDirection=[-1, -2, 3],
                                       shadow=0)[2]
                out["frames"].append(np.reshape(img, (h, w, 4))[:, :, :3].astype(np.uint8))
                out["t"].append(t * cfg.control_dt)
                out["x"].append(x)
            obs, _, term, trunc, info = env.step(policy(obs))
            if term[0] or trunc[0]:   # the env has reset the robot already: the outcome is info's final x
                out["final_x"], out["blowup"] = float(info["final_x"][0]), bool(info["blowup"][0])
                break
        return out
    finally:
        env.close()


def outcome(task: str, final_x, blowup: bool = False) -> tuple:
    """(text, colour) of an episode's end, by the curriculum's thresholds on the final pelvis x [facts]: past `up`
    the level is cleared (the next episode plays one up), short of `down` it falls back one, else it holds."""
    g = task_geometry(task)
    if final_x is None:
        return "cut short (--max-steps)", (90, 90, 90)
    if blowup:
        return f"blew up at x {final_x:.3f} m: level held", (150, 0, 150)
    if final_x > g["up"]:
        return f"CLEARED: final x {final_x:.3f} m > {g['up']} m, level up", (0, 130, 0)
    if final_x < g["down"]:
        return f"not cleared: final x {final_x:.3f} m < {g['down']} m, level down", (200, 0, 0)
    return f"not cleared: final x {final_x:.3f} m, level held", (200, 110, 0)


def level_text(task: str, level: int) -> str:
    """'level 28 = 28.1 cm obstacle' or 'level 40 = 17.8 deg ramp' (ballu.level_score) [facts]."""
    unit = "cm obstacle" if task == "obstacle" else "deg ramp"
    return f"level {level} = {float(level_score(task, level)):.1f} {unit}"


@functools.lru_cache(maxsize=1)
def _font():
    from PIL import ImageFont
    try:
        return ImageFont.load_default(size=12)
    except TypeError:   # Pillow < 10.1: its fixed bitmap font
        return ImageFont.load_default()


def caption(picture: np.ndarray, lines: list, last: tuple | None = None) -> np.ndarray:
    """The picture under a white header of text lines; `last` = (text, colour) for a final line."""
    from PIL import Image, ImageDraw
    font = _font()
    img = Image.new("RGB", (picture.shape[1], picture.shape[0] + HEADER), "white")
    img.paste(Image.fromarray(picture), (0, HEADER))
    draw = ImageDraw.Draw(img)
    for i, line in enumerate(lines):
        draw.text((5, 2 + 15 * i), line, fill=(0, 0, 0), font=font)
    if last:
        draw.text((5, 2 + 15 * len(lines)), last[0], fill=last[1], font=font)
    return np.asarray(img)


def panel_frames(films: list, task: str, level: int, hold_frames: int = 0) -> list:
    """Captioned frames of one or more films [(film, header lines), ...] side by side, frame i of each at the
    same time; a film that ended earlier holds its last frame. Each panel adds its time and x, and from its end
    on the outcome; the last frame is repeated `hold_frames` times."""
    n = max(len(f["frames"]) for f, _ in films)
    out = []
    for i in range(n):
        row = []
        for f, head in films:
            j = min(i, len(f["frames"]) - 1)
            end = j == len(f["frames"]) - 1 and (f["final_x"] is not None or i == n - 1)
            now = f"t {f['t'][j]:4.1f} s   x {f['x'][j]:5.2f} m   {level_text(task, level)}"
            row.append(caption(f["frames"][j], head + [now], outcome(task, f["final_x"], f["blowup"]) if end else None))
        out.append(np.concatenate(row, axis=1))
    return out + [out[-1]] * hold_frames


def check_writer(path: str) -> str | None:
    """The ffmpeg an .mp4 path needs (a RuntimeError if it is not installed), None for a GIF: checked before
    filming, so a missing ffmpeg costs no episode."""
    if not path.lower().endswith(".mp4"):
        return None
    if shutil.which("ffmpeg") is None:
        raise RuntimeError(f"{path}: MP4 needs ffmpeg on the PATH (not found); write a .gif instead")
    return shutil.which("ffmpeg")


def save_animation(path: str, frames: list, fps: float = 10.0) -> str:
    """Write RGB frames as a GIF (Pillow; any ending but .mp4) or an MP4 (ffmpeg: check_writer). Returns the path."""
    ffmpeg = check_writer(path)
    if ffmpeg:
        h, w = frames[0].shape[:2]
        cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
               "-r", str(fps), "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", path]
        subprocess.run(cmd, input=b"".join(np.ascontiguousarray(f).tobytes() for f in frames), check=True)
        return path
    from PIL import Image
    imgs = [Image.fromarray(f).quantize(colors=64, dither=Image.Dither.NONE) for f in frames]   # [ours] size
    imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=int(round(1000 / fps)), loop=0)
    return path
