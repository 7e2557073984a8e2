"""``imix render``: a saved policy acting in its env, as a GIF (or an MP4 when ffmpeg is present).

Why: a learning curve says how much a policy scores, not what it does; watching it is how one
spots a policy that exploits the time limit or balances by luck. Frames come from gymnasium's
``render_mode="rgb_array"`` of the policy's env (``env_id`` and episode cap from the policy file's
header), on the first of the seed's evaluation episodes (:func:`imix_cli.commands.eval_command.eval_episode_seeds`),
so the rendered episode is one that ``imix eval`` counts.

Backends (what to install):

* classic control (CartPole, Acrobot, imix/ContinuousCartPole*): pygame, i.e. ``pip install
  "gymnasium[classic-control]"`` (or imix's ``render`` extra). Drawn off-screen
  (``SDL_VIDEODRIVER=dummy`` is set when unset): no display needed.
* MuJoCo: ``pip install "gymnasium[mujoco]"`` and an off-screen OpenGL backend chosen by
  ``MUJOCO_GL``: ``egl`` (GPU or Mesa's EGL; ``apt install libegl1``) or ``osmesa`` (software,
  slower; ``apt install libosmesa6``). imix sets neither; a failure names both.
* GIFs are written with Pillow (a matplotlib dependency, always present); ``.mp4`` pipes raw
  frames to the ``ffmpeg`` executable, which must be on PATH.

The output file is written by the one writer (:mod:`imix_cli.running.files.writing`: a temporary file, then a rename;
no link followed inside the results folder), frame by frame: memory does not grow with the episode.
Without ``out=``, or with a relative ``out=``, it goes into the run folder, next to the policy it shows;
an absolute ``out=`` is written where it says.
"""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from imix_cli.commands.eval_command import POLICY_KEY_CHECKS, POLICY_KEYS, eval_episode_seeds, run_folders
from imix_cli.keyvalue import UsageError, at_least, help_requested, parse_key_values
from imix_cli.messages import EXIT_MISSING_EXTRA
from imix_cli.running.files.writing import atomic_writer

HELP = """\
usage: imix render [key=value ...]

Render one saved policy of a run (policy_<seed>_<which>.npz) acting in its env, on the first
episode imix eval uses for that seed, into a GIF (or an MP4 if ffmpeg is installed).

keys:
  results_dir=PATH   folder holding the experiments (default: results)
  experiment=NAME    experiment (default: default)
  run=NAME           run folder (needed when the experiment has several runs)
  seed=K             seed whose policy is shown (default: 0)
  which=mean|best    final distribution mean or best-ever member (default: mean)
  out=FILE           output, .gif or .mp4, overwritten if it exists; a relative
                     name is in the run folder (out=policy.gif: <run folder>/policy.gif),
                     an absolute one where it says (out=$PWD/policy.gif: the current
                     folder) (default: <run folder>/render-seed<K>-<which>.gif, never
                     overwritten)
  frames=N           at most N frames (default: the whole episode: reset + every step)
  scale=F            resize frames by F in (0, 1] (default: 1; 0.5 halves a GIF's size)
  fps=N              frames per second (default: the env's render_fps, else 30)
  import=MODULE[,..] modules to import for a run of your own env (env.id=MODULE:Id): a policy
                     file never makes imix import a module you did not name here

Needs pygame for classic control (pip install "gymnasium[classic-control]") and, for MuJoCo,
MUJOCO_GL=egl or MUJOCO_GL=osmesa.
"""

_MUJOCO_HINT = (
    "MuJoCo renders off-screen through OpenGL: set MUJOCO_GL=egl (needs libEGL, e.g. apt install libegl1) "
    'or MUJOCO_GL=osmesa (apt install libosmesa6), and pip install "gymnasium[mujoco]"'
)


def _one_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _is_mujoco(env_id: str) -> bool:
    import gymnasium as gym

    entry = gym.spec(env_id).entry_point
    return "mujoco" in str(entry).lower()


def make_render_env(header: dict, env_id: str, env_kwargs: dict | None = None):
    """``gym.make`` of the policy's env ``env_id`` (a registered id, resolved from the header by
    :func:`imix_cli.commands.eval_command.policy_env`: never a ``module:`` one) with ``render_mode="rgb_array"``;
    UsageError naming what to install: status 2 for a missing dependency (every missing extra's), 1 for another failure."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # pygame draws to a surface, no display
    import gymnasium as gym

    import imix_cli.core.envs  # noqa: F401  (registers imix/ ids)

    if ":" in env_id:
        raise UsageError(f"cannot render {env_id}: resolve the id first (a module: prefix is never imported here)", 1)
    try:
        with warnings.catch_warnings():  # CartPole-v0 "out of date": imix reproduces v0 on purpose
            warnings.simplefilter("ignore", DeprecationWarning)
            env = gym.make(env_id, render_mode="rgb_array", max_episode_steps=int(header["max_steps"]), **(env_kwargs or {}))
    except gym.error.DependencyNotInstalled as err:  # pygame, mujoco: a missing extra's one status
        raise UsageError(f"cannot render {env_id}: {_one_line(err)}", EXIT_MISSING_EXTRA) from None
    except Exception as err:  # noqa: BLE001 - GL and driver errors come in many types
        hint = _MUJOCO_HINT if _is_mujoco(env_id) else _one_line(err)
        raise UsageError(f"cannot render {env_id}: {hint}", 1) from None
    return env


def render_env_id(policy, allowed_modules=(), run_dir=None, where: str = "policy file") -> str:
    """The registered gymnasium id to render the policy in, its header checked as ``imix eval`` checks it."""
    from imix_cli.commands.eval_command import evaluator_for
    from imix_cli.core.envs.ids import plain_env_id
    from imix_cli.core.registry import BUILTIN_ENVS

    evaluator_for(policy.header, None, allowed_modules, run_dir, where)  # the same checks as eval: env, cap, shapes
    name = policy.header["env_name"]
    return BUILTIN_ENVS[name] if name in BUILTIN_ENVS else plain_env_id(policy.header["env_id"])


def policy_frames(policy, frames: int | None = None, env_id: str | None = None, env_kwargs: dict | None = None):
    """RGB frames (H, W, 3) uint8 of the policy's first evaluation episode: after reset, then after each step,
    yielded one at a time (a writer holds one or two at once: memory does not grow with the episode).

    ``env_id``: the registered id to render in (default: the header's, resolved with no module allowed).
    The env is made and its first frame drawn before the first yield returns, so a missing backend is
    reported (UsageError) before anything is written."""
    h = policy.header
    if h.get("obs_normalizer") is not None:
        raise UsageError(f"policy of run {h.get('run')!r} seed {h.get('seed')} normalises observations; this imix render cannot apply a normaliser yet", 1)
    env_id = env_id or render_env_id(policy)
    env = make_render_env(h, env_id, env_kwargs)  # env_kwargs: the run's env.kwargs (its config.yaml)
    act = policy.batch_policy(1)
    try:
        seed = int(eval_episode_seeds(h["seed"], 1)[0])
        try:
            obs, _ = env.reset(seed=seed)
            first = np.asarray(env.render())
        except Exception as err:  # noqa: BLE001
            if isinstance(err, ImportError) or "DependencyNotInstalled" in type(err).__name__:  # pygame, mujoco: a missing extra
                raise UsageError(f"cannot render {env_id}: {_one_line(err)}", EXIT_MISSING_EXTRA) from None
            hint = _MUJOCO_HINT if _is_mujoco(env_id) else _one_line(err)
            raise UsageError(f"cannot render {env_id}: {hint}", 1) from None
        yield first
        del first
        limit = frames if frames is not None else int(h["max_steps"]) + 1
        space = env.action_space
        for _ in range(limit - 1):
            flat = np.asarray(obs, dtype=np.float64).reshape(-1)
            if flat.size != int(h["obs_dim"]):
                from imix_cli.core.evaluation import UserEnvError

                raise UserEnvError(env_id, f"step returned an observation of shape {np.shape(obs)}; the policy takes {h['obs_dim']} numbers")
            a = act(flat.reshape(1, -1))
            if h["discrete"]:
                action = int(a[0]) + int(h.get("action_start") or 0)
            else:
                action = np.asarray(a[0]).reshape(space.shape).astype(space.dtype)
            try:
                obs, _, terminated, truncated, _ = env.step(action)
                frame = np.asarray(env.render())
            except Exception as err:  # noqa: BLE001 - the env's own code: one line naming it (imix_cli.commands.boundary)
                from imix_cli.core.evaluation import UserEnvError

                raise UserEnvError.wrap(env_id, "step", err) from err
            yield frame
            if terminated or truncated:
                break
    finally:
        env.close()


def _image(frame, scale: float):
    """One frame as an RGB Pillow image, resized by ``scale``."""
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(frame[..., :3]).astype(np.uint8))
    if scale != 1.0:
        image = image.resize((max(1, round(image.width * scale)), max(1, round(image.height * scale))), Image.Resampling.LANCZOS)
    return image


def write_gif(fh, frames, fps: float, scale: float = 1.0) -> int:
    """An endlessly looping GIF (adaptive 256-colour palette per frame) streamed to the binary file ``fh``; returns
    the number of frames.

    Streamed: each frame is encoded as it comes (Pillow's ``GifImagePlugin.getdata``), so memory is two frames and
    one encoded frame, whatever the episode's length (Pillow's ``save_all`` holds every frame). Only the rectangle
    that changed since the frame before is stored (drawn over it: disposal 1), and a frame identical to the one
    before is stored as a longer display of that frame; the total duration is always ``frames / fps``.
    """
    from PIL import GifImagePlugin, Image, ImageChops

    delay = max(20, round(1000 / fps))
    count, held, held_ms, previous = 0, None, 0, None

    def emit(piece, offset, duration: int) -> None:
        for chunk in GifImagePlugin.getdata(piece, offset, duration=duration, disposal=1, include_color_table=True):  # each its own palette
            fh.write(chunk)

    for frame in frames:
        image = _image(frame, scale)
        count += 1
        box = (0, 0, *image.size) if previous is None else ImageChops.difference(previous, image).getbbox()
        if box is None:  # the same picture as the frame before
            held_ms += delay
            continue
        piece = image.crop(box).convert("P", palette=Image.Palette.ADAPTIVE, colors=256)
        if previous is None:
            header, _ = GifImagePlugin.getheader(piece, info={"loop": 0})  # logical screen (the whole first frame), looping forever
            for chunk in header:
                fh.write(chunk)
        if held is not None:
            emit(*held, held_ms)
        held, held_ms, previous = (piece, box[:2]), delay, image
    if held is not None:
        emit(*held, held_ms)
    fh.write(b";")  # the GIF trailer
    return count


def write_mp4(fh, frames, fps: float, scale: float = 1.0) -> int:
    """H.264 MP4 through the ``ffmpeg`` executable (UsageError naming it if absent) into the binary file ``fh``;
    frames are piped one at a time (memory does not grow with the episode). Returns the number of frames."""
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise UsageError("writing .mp4 needs the ffmpeg executable on PATH (e.g. apt install ffmpeg); out=<name>.gif needs nothing", 1)
    frames = iter(frames)
    first = _image(next(frames), scale)
    w, h = first.size
    cmd = [
        ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", f"{fps:g}",
        "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-c:v", "libx264", "-f", "mp4", f"/dev/fd/{fh.fileno()}",
    ]  # fmt: skip
    # ffmpeg writes the writer's temporary file through its descriptor (an MP4 needs a seekable output, not a pipe)
    with tempfile.TemporaryFile() as errors:
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=errors, pass_fds=(fh.fileno(),))
        count = 0
        try:
            for image in _chain(first, frames, scale):
                proc.stdin.write(image.tobytes())
                count += 1
            proc.stdin.close()
        except BrokenPipeError:
            pass  # ffmpeg stopped: its message is read below
        finally:
            returncode = proc.wait()
        if returncode != 0:
            errors.seek(0)
            raise UsageError(f"ffmpeg failed: {_one_line(RuntimeError(errors.read(4096).decode(errors='replace')))}", 1)
    return count


def _chain(first, frames, scale: float):
    yield first
    for frame in frames:
        yield _image(frame, scale)


def default_out(run_dir: Path, seed: int, which: str) -> Path:
    """Where a render goes without ``out=``: into the run folder, next to the policy it shows."""
    return Path(run_dir) / f"render-seed{seed}-{which}.gif"


def _pick_run(folders: list, run: str | None) -> Path:
    if run is not None or len(folders) == 1:
        return folders[0]
    raise UsageError(f"the experiment has {len(folders)} runs; choose one with run= ({', '.join(p.name for p in folders)})")


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, HELP):
        return 0
    from imix_cli.running.files.policy_files import PolicyFileError, policy_path, read_policy

    try:
        s = parse_key_values(
            argv, "render",
            {**POLICY_KEYS, "seed": 0, "out": None, "frames": None, "scale": "1", "fps": None},
            convert={**POLICY_KEY_CHECKS, "seed": at_least(0), "frames": at_least(1), "fps": at_least(1)},
        )  # fmt: skip
        out = Path(s["out"] or "policy.gif").expanduser()
        if out.suffix.lower() not in (".gif", ".mp4"):
            raise UsageError(f"bad value for out: {s['out']!r} (expected a .gif or .mp4 file name)")
        try:
            scale = float(s["scale"])
        except ValueError:
            scale = -1.0
        if not 0.0 < scale <= 1.0:
            raise UsageError(f"bad value for scale: {s['scale']!r} (expected a number in (0, 1])")
        run_dir = _pick_run(run_folders(s["results_dir"], s["experiment"], s["run"]), s["run"])
        # An absolute out= is the user's own path (its folder may be a link they chose); a relative one names a file in
        # the run folder, next to the policy it shows (out=reach.gif went into the current folder), as the default
        # does: inside the results folder, below which the writer follows no link.
        outside = s["out"] is not None and out.is_absolute()
        if s["out"] is not None and not outside:
            out = run_dir / out
        root = out.parent if outside else s["results_dir"]
        if s["out"] is not None and not out.parent.is_dir():
            raise UsageError(f"bad value for out: folder {out.parent} does not exist")
        if s["out"] is None:  # a name of its own, and an earlier render is never replaced without out= saying so
            out = default_out(run_dir, s["seed"], s["which"])
            if out.exists() or out.is_symlink():
                raise UsageError(f"{out} exists; give out={out.name} to overwrite it (a relative out= is in the run folder), or another out= name", 1)
        path = policy_path(run_dir, s["seed"], s["which"])
        policy = read_policy(path)
        env_id = render_env_id(policy, s["import"], run_dir, str(path))
        from imix_cli.commands.eval_command import config_env_kwargs

        frames = policy_frames(policy, s["frames"], env_id, config_env_kwargs(run_dir))
        first = next(frames)  # the env made and its first frame drawn before the output file is opened
        import gymnasium as gym

        fps = s["fps"] or gym.spec(env_id).kwargs.get("render_fps") or _env_fps(env_id)
        write = write_mp4 if out.suffix.lower() == ".mp4" else write_gif
        with atomic_writer(out, root=root) as fh:
            count = write(fh, itertools.chain([first], frames), float(fps), scale)
    except UsageError as err:
        print(f"imix render: {err}", file=sys.stderr)
        return err.status
    except PolicyFileError as err:
        print(f"imix render: {err}", file=sys.stderr)
        return 1
    except OSError as err:  # a link refused by the writer, a full disk: the file named keeps its old content
        where = f" {err.filename}" if err.filename else ""
        print(f"imix render: error: cannot write{where}: {err.strerror or err}", file=sys.stderr)
        return 1
    print(f"wrote {out} ({count} frames, {out.stat().st_size / 1024:.0f} KiB, {policy.header['env_id']}, seed {s['seed']}, {s['which']})")
    return 0


def _env_fps(env_id: str) -> int:
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    entry = gym.spec(env_id).entry_point
    creator = load_env_creator(entry) if isinstance(entry, str) else entry
    return int(getattr(creator, "metadata", {}).get("render_fps") or 30)


if __name__ == "__main__":
    sys.exit(main())
