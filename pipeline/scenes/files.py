"""Scene files: where the shipped scenes live, finding one by name or path, reading and validating it.

A scene is one TOML file under ``data/scenes/``; :func:`load_scene` reads one and :func:`parse_scene
<pipeline.scenes.parse.parse_scene>` validates it. :func:`scene_hash` turns a scene name into the stable
integer every job's random stream is seeded with (docs/simulation.md, "`stucco collect`"). A scene is told
apart from a shipped one by its content, never by its name: :func:`shipped_digest` and :func:`shadows_shipped`
(a user's file named like a shipped scene but with other content, which ``stucco collect`` refuses and the
report never compares with the paper).
"""
from __future__ import annotations

import hashlib
import tomllib
from dataclasses import replace
from pathlib import Path

from pipeline.safe_open import NotRegularFile, optional_file, read_bytes
from pipeline.scenes.parse import parse_scene
from pipeline.scenes.types import Scene, SceneError

__all__ = ["SCENE_DIR", "scene_names", "scene_path", "scene_hash", "load_scene", "load_all", "scene_from_text",
           "scene_digest", "shipped_digest", "shadows_shipped"]

#: Directory of the shipped scene files (``data/scenes/`` at the repository root).
SCENE_DIR = Path(__file__).resolve().parents[2] / "data" / "scenes"


def scene_names(directory: Path = SCENE_DIR) -> list[str]:
    """Names of the scene files in ``directory``, sorted."""
    return sorted(p.stem for p in Path(directory).glob("*.toml"))


def scene_path(name_or_path: str | Path, directory: Path = SCENE_DIR) -> Path:
    """The file of a scene given by name (``"FB"``) or by path to a ``.toml`` file."""
    text = str(name_or_path)
    if text.endswith(".toml") or "/" in text or "\\" in text:
        path = Path(text)
        try:
            if optional_file(path, "the scene file") is None:
                raise SceneError(f"{path}: scene file does not exist")
        except NotRegularFile as e:  # a FIFO would block the reader
            raise SceneError(str(e)) from None
        return path
    path = Path(directory) / f"{text}.toml"
    if not path.is_file():
        known = ", ".join(scene_names(directory)) or "none"
        raise SceneError(f"{path}: unknown scene {text!r} (known: {known})")
    return path


def scene_hash(name: str) -> int:
    """A stable 32-bit integer for a scene name, the middle entry of every job's SeedSequence."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def load_all(directory: Path = SCENE_DIR) -> list[Scene]:
    """Every scene in ``directory``, sorted by name."""
    return [load_scene(n, directory) for n in scene_names(directory)]


def load_scene(name_or_path: str | Path, directory: Path = SCENE_DIR) -> Scene:
    """Read and validate a scene by name (``"FB"``) or path.

    Raises
    ------
    SceneError
        Unknown scene, unreadable or invalid TOML, or a missing/ill-typed key; one line naming file and key.
    """
    path = scene_path(name_or_path, directory)
    try:
        text = read_bytes(path, "the scene file").decode("utf-8")
    except NotRegularFile as exc:
        raise SceneError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a TOML text file (byte {exc.start} is not UTF-8)") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror}") from None
    return scene_from_text(text, path)


def scene_from_text(text: str, path: Path) -> Scene:
    """Parse and validate a scene's TOML ``text`` (``path`` names it in errors; its stem is the default name)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    return replace(parse_scene(data, path), source=text)


def scene_digest(text: str) -> str:
    """Hex SHA-256 of a scene's TOML text (UTF-8): what a run file records of the scene it was collected in."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def shipped_digest(name: str, directory: Path = SCENE_DIR) -> str | None:
    """:func:`scene_digest` of the shipped scene ``name`` (its file in ``directory``), None when no scene of that
    name is shipped (or its file cannot be read as text)."""
    if not isinstance(name, str) or name not in scene_names(directory):
        return None
    try:
        return scene_digest(read_bytes(Path(directory) / f"{name}.toml", "the scene file").decode("utf-8"))
    except (OSError, UnicodeDecodeError, NotRegularFile):
        return None


def shadows_shipped(scene: Scene, directory: Path = SCENE_DIR) -> bool:
    """Whether ``scene`` bears the name of a shipped scene but not its content (a byte-identical copy does not)."""
    digest = shipped_digest(scene.name, directory)
    return digest is not None and scene_digest(scene.source) != digest
