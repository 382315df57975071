"""Parameter sweeps: a scene run at the product of ``--vary`` values (and ``--repeat`` times),
each variant a normal run folder under the sweep's folder, with ``sweep.json`` and a chart.

```
SWEEP/sweep.json                       the settings, and every variant: its settings, how it ended,
                                       its wall time and its run.json's summary (SUMMARY)
SWEEP/sweep.png                        a measure against the varied keys
SWEEP/spacing=0.02,physics.eta=0.001/  one variant's run folder (run.json, stats.jsonl, particles/)
```

A variant's folder is named by its settings (sanitised to a plain folder name; a hash keeps it
unique when the text had to change) and builds its scene from the scene file with the sweep's
``--set`` and its own settings, exactly as ``warp-iisph run --set`` does: it is the same run,
bitwise. ``sweep.json`` is rewritten (atomically) as variants end and however the sweep ends; a
variant whose run folder says it completed (or diverged: a result, not a failure) is not run again
by ``--resume``.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import itertools
import json
import math
import re
import sys
import time
from pathlib import Path

from ..scene import load_scene, scene_fingerprint, scene_to_dict
from ..scene.file import parse_value
from ..scene.library import bundled_scenes, resolve_scene
from .atomic import write_json
from .folder import RECORD, RunError, run_around
from .lock import LOCK_NAME, FolderLock
from .progress import frame_bar
from .run_record import blank_record, run_warnings
from .runner import Terminated, plan_frames
from .sweep_chart import DEFAULT_MEASURE, DONE, SUMMARY, _bare, chart, check_measure

SWEEP = "sweep.json"
CHART = "sweep.png"
MAX_VARIANTS = 10_000
MAX_REPEAT = 1000
MAX_NAME = 100


# --- the variants ----------------------------------------------------------------------------------


def split_values(text: str) -> list[str]:
    """``V1,V2,...`` split at the commas outside brackets and quotes (``[0,1],[1,0]`` is two values)."""
    values, current, depth, quote = [], [], 0, None
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            values.append("".join(current).strip())
            current = []
            continue
        current.append(ch)
    values.append("".join(current).strip())
    return values


def _comparable(value):
    """A parsed ``--vary`` value with its numbers as floats (1000 and 1000.0 are one value)."""
    if isinstance(value, list):
        return [_comparable(v) for v in value]
    if isinstance(value, dict):
        return {k: _comparable(v) for k, v in value.items()}
    return float(value) if isinstance(value, int) and not isinstance(value, bool) else value


def parse_vary(specs: list[str], sets: list[str] = ()) -> dict[str, list[str]]:
    """``--vary KEY=V1,V2,...`` options as {key: [value texts]}, in the order given; ``ValueError``
    naming the option for a malformed one, a key given twice, or a key also given with ``--set``."""
    vary: dict[str, list[str]] = {}
    fixed = {s.partition("=")[0].strip() for s in sets}
    for spec in specs:
        key, eq, text = spec.partition("=")
        key = key.strip()
        if not eq or not key or any(c.isspace() for c in key):
            raise ValueError(f"--vary {spec!r}: must be KEY=V1,V2,..., e.g. --vary spacing=0.02,0.01")
        values = split_values(text)
        if any(not v for v in values):
            raise ValueError(f"--vary {spec!r}: an empty value (values are separated by commas)")
        # the same value written twice, or as two spellings of one number (0.001 and 1e-3)
        if len({json.dumps(_comparable(parse_value(v)), sort_keys=True, default=str) for v in values}) != len(values):
            raise ValueError(f"--vary {spec!r}: a value given twice")
        if key in vary:
            raise ValueError(f"--vary {key}: given twice (put all its values in one --vary)")
        if key in fixed:
            raise ValueError(f"--vary {key}: also given with --set")
        vary[key] = values
    return vary


# what variant_name makes: one folder name, never ".", ".." or hidden, never a path
FOLDER_NAME = re.compile(r"(?!\.)(?!.*\.\.)[A-Za-z0-9._=,+~-]+")


def variant_name(settings: dict[str, str], repeat: int | None = None) -> str:
    """The folder of a variant: ``key=value`` pairs joined by commas (``repeat=k`` last for a
    repeated one), with any character but letters, digits and ``._=,+-`` replaced, no leading
    dot or dash and no ``..``; a hash of the settings is added when the text changed or was cut,
    so distinct settings never share a folder."""
    pairs = [f"{k}={_bare(v)}" for k, v in settings.items()] + ([f"repeat={repeat}"] if repeat is not None else [])
    text = ",".join(pairs) or "default"
    name = re.sub(r"\.{2,}", "_", re.sub(r"[^A-Za-z0-9._=,+-]", "_", text)).lstrip(".-")
    if name != text or len(name) > MAX_NAME:
        digest = hashlib.sha1(json.dumps([settings, repeat]).encode()).hexdigest()[:8]
        name = f"{name[: MAX_NAME - 9]}~{digest}".lstrip(".-~") or digest
    return name


def variants(vary: dict[str, list[str]], repeat: int = 1) -> list[dict]:
    """The product of the values (the last key varying fastest), each ``repeat`` times: one
    sweep.json entry each, not yet run."""
    out = []
    for combo in itertools.product(*vary.values()):
        settings = dict(zip(vary, combo))
        for k in range(1, repeat + 1) if repeat > 1 else (None,):
            out.append(
                {
                    "name": variant_name(settings, k),
                    "settings": settings,
                    "repeat": k or 1,
                    "ended": "pending",
                    "message": "",
                    "wall_seconds": None,
                    "worker": None,
                    "summary": {},
                }
            )
    return out


def overrides(record: dict, entry: dict) -> list[str]:
    """The ``--set`` assignments a variant's scene is built with: the sweep's, then its own."""
    return list(record["set"]) + [f"{k}={v}" for k, v in entry["settings"].items()]


def scene_digest(built) -> str:
    """A hash of the scene the variants are built from (the scene file built with the sweep's
    ``--set``: every key, and its mesh files' contents): a resume whose scene changed would mix
    variants of two scenes in one sweep."""
    whole = {"scene": scene_to_dict(built), "meshes": scene_fingerprint(built)["meshes"]}
    return hashlib.sha256(json.dumps(whole, sort_keys=True, default=str).encode()).hexdigest()


def check_scene_unchanged(record: dict, where) -> None:
    """``RunError`` when the scene of sweep ``record`` is not the one its variants were run from (a
    sweep of an older version, with no digest, is not checked)."""
    taken = record.get("scene_digest")
    if taken is None:
        return
    try:
        now = scene_digest(load_scene(record["scene"], list(record["set"])))
    except ValueError as e:
        raise RunError(f"{where}: its scene no longer builds: {e}") from None
    if now != taken:
        raise RunError(
            f"{where}: its scene {record['scene']} (or a mesh file it reads) changed since the sweep began; "
            "the variants run now would not be comparable with those run before: restore it, or start a new sweep"
        )


# --- sweep.json ------------------------------------------------------------------------------------


def plan_sweep(
    scene: str,
    vary_specs: list[str],
    sets: list[str] = (),
    repeat: int = 1,
    duration: float | None = None,
    fps: float | None = None,
    device: str = "cpu",
    graph: bool = False,
    out=None,
    measure: str = DEFAULT_MEASURE,
) -> tuple[dict, Path]:
    """A new sweep's record and folder, every variant's scene built and checked first (nothing on
    disk changes): ``ValueError`` naming the option or the variant otherwise."""
    check_measure(measure)
    if not 1 <= repeat <= MAX_REPEAT:
        raise ValueError(f"--repeat {repeat}: must be in [1, {MAX_REPEAT}]")
    vary = parse_vary(vary_specs, sets)
    for key, option, given in (("output.duration", "--duration", duration), ("output.fps", "--fps", fps)):
        if given is not None and key in vary:
            raise ValueError(f"--vary {key}: also given with {option}")
    if not vary and repeat == 1:
        raise ValueError("--vary KEY=V1,V2,...: at least one (or --repeat N to time one setting N times)")
    count = math.prod(len(v) for v in vary.values()) * repeat
    if count > MAX_VARIANTS:
        raise ValueError(f"--vary: {count} variants; at most {MAX_VARIANTS} in one sweep")
    source = resolve_scene(scene)
    # a bundled scene is kept by name (found on every worker), a file by its absolute path
    scene = scene if bundled_scenes().get(scene) == source else str(source.resolve())
    base = load_scene(scene, list(sets))
    record = {
        "scene": scene,
        "set": list(sets),
        "vary": vary,
        "repeat": repeat,
        "duration": duration,
        "fps": fps,
        "device": device,
        "graph": graph,
        "measure": measure,
        "scene_digest": scene_digest(base),
        "ended": "pending",
        "message": "",
        "sessions": [],
        "variants": variants(vary, repeat),
    }
    check_measure(measure, variant_blanks(record, skip_broken=False))
    names = [e["name"] for e in record["variants"]]
    if len(set(names)) != len(names):  # only a hash collision could do it
        raise ValueError("--vary: two variants would share a folder name")
    out = Path(out) if out is not None else Path("sweeps") / base.name
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file, not a folder")
    inside = run_around(out)
    if inside is not None:  # its variants' runs would sit inside another run's folder
        raise ValueError(f"--out {out}: inside the run folder {inside}; put the sweep elsewhere")
    if out.is_dir() and any(out.iterdir()):
        hint = "; --resume it to run what it has left" if (out / SWEEP).is_file() else ""
        raise ValueError(f"--out {out}: folder exists and is not empty{hint}")
    return record, out


def blank_summary(scene, plan, device: str = "cpu") -> dict:
    """The summary a variant's entry will keep of a run of ``scene`` over ``plan``, before it
    runs: its names and parts as the run will write them, every count 0
    (:func:`~warp_iisph.run.run_record.blank_record`)."""
    return summary(blank_record(scene, plan, device))


def variant_blanks(record: dict, skip_broken: bool) -> list[dict]:
    """The summaries the variants of sweep ``record`` will have (:func:`blank_summary`; a repeat's
    is its first's), for ``--measure``. A variant whose scene does not build is a ``ValueError``
    naming it, or with ``skip_broken`` left out (a resumed sweep: it fails when it runs, and says
    why)."""
    blanks = []
    for entry in record["variants"]:
        if entry.get("repeat", 1) > 1:
            continue  # a repeat builds the same scene as the first
        try:
            built = load_scene(record["scene"], overrides(record, entry))
            blanks.append(blank_summary(built, plan_frames(built, record["duration"], record["fps"]), record["device"]))
        except ValueError as e:
            if not skip_broken:
                raise ValueError(f"variant {entry['name']}: {e}") from None
    return blanks


def resumed_measure(record: dict, measure: str) -> str:
    """``measure`` for a resumed sweep's chart, checked as :func:`plan_sweep` checks a new
    sweep's against the summaries its variants will have."""
    return check_measure(measure, variant_blanks(record, skip_broken=True))


def load_sweep(path) -> dict:
    """The record of the sweep in folder ``path`` (``RunError`` when it has none)."""
    path = Path(path)
    file = path / SWEEP
    if not file.is_file():
        raise RunError(f"{path}: no {SWEEP} (not a sweep folder)")
    try:
        record = json.loads(file.read_text())
        if not isinstance(record.get("variants"), list) or "scene" not in record:
            raise KeyError
    except json.JSONDecodeError as e:
        raise RunError(f"{file}: not valid JSON ({e.msg}, line {e.lineno})") from None
    except (KeyError, AttributeError):
        raise RunError(f"{file}: not a sweep record") from None
    inside = run_around(path)
    if inside is not None:  # its variants' runs would sit inside another run's folder
        raise RunError(f"{path}: inside the run folder {inside}; move the sweep out of it to resume it")
    _check_record_fields(record, file)
    record.setdefault("vary", {})
    names = set()
    for k, entry in enumerate(record["variants"]):
        # each variant's folder is overwritten when it runs: its name must be one folder inside the sweep's
        name = entry.get("name") if isinstance(entry, dict) else None
        if not isinstance(name, str) or not FOLDER_NAME.fullmatch(name) or name in names:
            raise RunError(
                f"{file}: variants[{k}].name = {name!r:.80}: not a variant folder's name "
                "(letters, digits and ._=,+~- in one folder inside the sweep's, each once); the file was edited"
            )
        settings = entry.get("settings")
        if (
            not isinstance(settings, dict)
            or list(settings) != list(record["vary"])
            or any(v not in record["vary"][key] for key, v in settings.items())
            or type(entry.get("repeat", 1)) is not int
            or entry.get("repeat", 1) < 1
        ):
            raise RunError(
                f"{file}: variants[{k}].settings: not settings of the sweep's 'vary' (or a repeat); the file was edited"
            )
        names.add(name)
    return record


def _check_record_fields(record: dict, file: Path) -> None:
    """``RunError`` naming the first field of a sweep record that is not what a sweep writes."""
    number = lambda v: v is None or (isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0)  # noqa: E731
    fields = {
        "scene": lambda v: isinstance(v, str) and bool(v),
        "set": lambda v: isinstance(v, list) and all(isinstance(a, str) for a in v),
        "vary": lambda v: (
            isinstance(v, dict) and all(isinstance(x, list) and all(isinstance(a, str) for a in x) for x in v.values())
        ),
        "repeat": lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_REPEAT,
        "duration": number,
        "fps": number,
        "device": lambda v: isinstance(v, str),
        "graph": lambda v: isinstance(v, bool),
        "measure": lambda v: isinstance(v, str),
    }
    for key, ok in fields.items():
        if key in record and not ok(record[key]):
            raise RunError(f"{file}: {key} = {record[key]!r:.80}: not what a sweep writes there; the file was edited")


@contextlib.contextmanager
def claim(out, resume: bool):
    """Hold sweep folder ``out``'s lock while a sweep writes it (``FolderBusy`` naming the sweep
    that holds it). Under the lock a new sweep's folder is checked to be still empty, and a
    resumed one's record is read again (yielded) and its scene checked unchanged."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with FolderLock(out, "sweep folder"):
        if resume:
            record = load_sweep(out)
            check_scene_unchanged(record, out / SWEEP)
            yield record
        else:
            if any(p.name != LOCK_NAME for p in out.iterdir()):  # another sweep began here meanwhile
                raise RunError(f"--out {out}: folder exists and is not empty")
            yield None


def save(record: dict, out: Path) -> None:
    counts: dict[str, int] = {}
    for e in record["variants"]:
        counts[e["ended"]] = counts.get(e["ended"], 0) + 1
    record["counts"] = counts
    write_json(out / SWEEP, record)


def _run_record(folder: Path) -> dict:
    try:
        return json.loads((folder / RECORD).read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def summary(run_record: dict) -> dict:
    """What a variant's entry in sweep.json keeps of its run.json, with the warnings its run ended
    with (:func:`.run_record.run_warnings`)."""
    kept = {k: run_record[k] for k in SUMMARY if k in run_record}
    if "totals" in run_record and "scene" in run_record:
        kept["warnings"] = run_warnings(run_record)
    return kept


# --- running ---------------------------------------------------------------------------------------


def one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text if isinstance(e, ValueError) and text else f"{type(e).__name__}: {text}".rstrip(": ")


def run_variant(
    scene: str, assignments: list[str], out: str, duration, fps, device: str, graph: bool, command: list[str]
) -> dict:
    """Run one variant into its folder (replacing what a stopped attempt left there): how it
    ended, its wall time and its run.json's summary. Every error is caught and told in one line.
    ``command``: the sweep's command line, which the run records as the one that made it."""
    from .cluster import in_worker, stop_when_cancelled, task_device, worker_name
    from .runner import run_scene

    t0 = time.perf_counter()
    argv, sys.argv = sys.argv, list(command)  # a worker's own command line is Dask's
    try:
        with stop_when_cancelled():  # on a cluster, a stopped sweep stops its runs as Ctrl-C would
            record = run_scene(
                load_scene(scene, assignments),
                out,
                duration,
                fps,
                task_device(device),
                overwrite=True,
                progress=False,
                graph=graph,
            )
        ended, message, kept = record["ended"], record["message"], summary(record)
    except KeyboardInterrupt:
        if not in_worker():  # in this process, Ctrl-C stops the sweep
            raise
        ended, message, kept = "interrupted", "stopped before its run began", {}
    except Exception as e:  # noqa: BLE001 - the variant failed; the others go on
        ended, message, kept = "failed", one_line(e), {}
    finally:
        sys.argv = argv
    return {
        "ended": ended,
        "message": message,
        "wall_seconds": time.perf_counter() - t0,
        "worker": worker_name(),
        "summary": kept,
    }


def run_sweep(record: dict, out, workers, progress: bool = True) -> dict:
    """Run the variants of ``record`` not yet complete (their run folder's run.json says
    completed or diverged) on ``workers`` (:class:`~warp_iisph.run.cluster.Workers`), keeping
    ``sweep.json`` in ``out`` up to date; then draw the chart. Returns the record, whose
    ``ended`` is ``completed`` when every variant ran (each entry says how it ended). Ctrl-C
    (or SIGTERM) stops the sweep: the record says so and what each variant got to, then the
    interrupt goes on."""
    out = Path(out)
    entries = record["variants"]
    for e in entries:  # the run folders say what is done, whatever an earlier sweep.json said
        run = _run_record(out / e["name"])
        if run.get("ended") in DONE:
            e.update(ended=run["ended"], message=run.get("message", ""), summary=summary(run))
        else:
            e.update(ended="pending", message="")
    todo = [e for e in entries if e["ended"] not in DONE]
    session = {
        "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "variants_run": len(todo),
        "workers": workers.describe(),
    }
    record.setdefault("sessions", []).append(session)
    record.update(ended="running", message="")
    out.mkdir(parents=True, exist_ok=True)
    save(record, out)
    calls = [
        (
            run_variant,
            (
                record["scene"],
                overrides(record, e),
                str((out / e["name"]).resolve()),
                record["duration"],
                record["fps"],
                record["device"],
                record["graph"],
                list(sys.argv),
            ),
        )
        for e in todo
    ]

    def on_start(i: int) -> None:
        todo[i]["ended"] = "running"
        save(record, out)

    def on_done(i: int, result: dict | None, error: BaseException | None) -> None:
        if error is not None:  # the task never reported: its worker was lost
            result = {"ended": "failed", "message": one_line(error), "wall_seconds": None, "worker": None}
            result["summary"] = {}
        todo[i].update(result)
        save(record, out)
        bar.update(1)
        if workers.serial and result["ended"] == "terminated":  # the variant took this process's signal: stop
            raise Terminated()
        if workers.serial and result["ended"] == "interrupted":
            raise KeyboardInterrupt()

    bar = frame_bar(len(entries), progress, "sweep", unit="variant")
    bar.update(len(entries) - len(todo))
    t0 = time.perf_counter()
    ended, message = "failed", ""
    try:
        workers.run(calls, on_done, on_start, gpu=record["device"] == "cuda", name="variant", wait_on_stop=True)
        ended = "completed"
    except Terminated:
        ended, message = "terminated", "terminated"
        raise
    except KeyboardInterrupt:
        ended, message = "interrupted", "interrupted"
        raise
    except Exception as e:
        message = one_line(e)
        raise
    finally:
        bar.close()
        for e in todo:  # a variant that did not report: its run folder (if any) says how far it got
            if e["ended"] in ("pending", "running"):
                run = _run_record(out / e["name"])
                if run.get("ended") in DONE:
                    e.update(ended=run["ended"], message=run.get("message", ""), summary=summary(run))
                elif run:
                    e.update(ended="interrupted", message=run.get("message") or "stopped while running")
        session["wall_seconds"] = time.perf_counter() - t0
        record.update(ended=ended, message=message)
        save(record, out)
    record["chart"] = chart(record, out / CHART)
    if record["chart"] is None and (out / CHART).is_file():  # a chart of another measure would mislead
        (out / CHART).unlink()
    save(record, out)
    return record


# --- the chart -------------------------------------------------------------------------------------
