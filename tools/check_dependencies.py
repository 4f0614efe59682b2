#!/usr/bin/env python3
"""Refuses known-compromised package releases before (and after) they are installed.

Usage::

    python tools/check_dependencies.py requirements.lock             # before `pip install`
    python tools/check_dependencies.py --installed                   # the running environment
    python tools/check_dependencies.py requirements.lock --require-hashes --installed

Each file is read as a pip requirements file (``name==version`` lines, ``\\`` continuations,
``--hash`` options, ``-r``/``-c`` includes). A requirement is refused when it pins a release listed in
the deny-list (``tools/compromised_releases.txt``: ``name==version  # why``) or, unpinned, when its
version range allows one (checked with ``packaging`` when importable, otherwise refused as unprovable).
``--installed`` also checks every distribution importable in this interpreter. ``--require-hashes``
refuses a requirement without a ``--hash``. Exit status: 0 clean, 1 refused (one line per finding on
stderr), 2 unreadable input. Standard library only, so it runs in a fresh virtual environment.

Example:
    >>> deny = {("litellm", "1.82.7"): "credential stealer"}
    >>> [finding.split(": ", 1)[1] for finding in check_requirement("litellm==1.82.7", "lock:3", deny)]
    ['litellm==1.82.7 is a known-compromised release (credential stealer)']
    >>> check_requirement("litellm==1.102.4", "lock:3", deny)
    []
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterator
from pathlib import Path

DEFAULT_DENY_LIST = Path(__file__).with_name("compromised_releases.txt")
DenyList = dict[tuple[str, str], str]  # (normalised name, normalised version) -> reason
_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(\[[^\]]*\])?\s*(.*)$")


def normalise_name(name: str) -> str:
    """PEP 503 name: lower case, each run of ``-_.`` as one ``-`` (``Lite_LLM`` -> ``lite-llm``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def normalise_version(version: str) -> str:
    """A comparable release string: lower case, no leading ``v``, no local label, no trailing ``.0``s."""
    version = version.strip().lower().removeprefix("v").split("+", 1)[0]
    while re.search(r"\.0$", version) and version.count(".") > 0:
        version = version[:-2]
    return version


def load_deny_list(path: Path) -> DenyList:
    denied: DenyList = {}
    for number, raw in enumerate(path.read_text().splitlines(), 1):
        line, _, reason = raw.partition("#")
        if not line.strip():
            continue
        name, separator, version = line.strip().partition("==")
        if not separator or not name.strip() or not version.strip():
            raise ValueError(f"{path}:{number}: expected 'name==version  # why', got {raw!r}")
        denied[(normalise_name(name), normalise_version(version))] = reason.strip() or "listed"
    return denied


def logical_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(first line number, text) of each requirement line, continuations joined, comments dropped."""
    pending, start = "", 0
    for number, raw in enumerate(path.read_text().splitlines(), 1):
        line = re.sub(r"(^|\s)#.*$", "", raw).rstrip()
        if not pending:
            start = number
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        text = (pending + line).strip()
        pending = ""
        if text:
            yield start, text
    if pending.strip():
        yield start, pending.strip()


def check_requirement(text: str, where: str, denied: DenyList, require_hashes: bool = False) -> list[str]:
    """Findings (empty = fine) for one requirement line such as ``name[extra]==1.2 ; marker --hash=...``."""
    has_hash = "--hash" in text
    text = re.split(r"\s--hash", " " + text, maxsplit=1)[0].strip()
    requirement = text.split(";", 1)[0].strip()  # environment markers do not change what may be installed
    match = _NAME.match(requirement)
    if not match or "://" in requirement or requirement.startswith((".", "/")):
        return []  # a path or URL requirement: nothing to compare by name
    name, specifier = normalise_name(match.group(1)), match.group(3).replace(" ", "")
    findings = []
    if require_hashes and not has_hash:
        findings.append(f"{where}: {name} has no --hash (the lock must pin every file by its sha256)")
    listed = {version: reason for (denied_name, version), reason in denied.items() if denied_name == name}
    if not listed:
        return findings
    pinned = re.fullmatch(r"===?([^,]+)", specifier)
    if pinned:
        version = normalise_version(pinned.group(1))
        if version in listed:
            findings.append(f"{where}: {name}=={pinned.group(1)} is a known-compromised release ({listed[version]})")
        return findings
    for version, reason in listed.items():
        if _allows(specifier, version):
            findings.append(
                f"{where}: {name}{specifier or ' (any version)'} allows {name}=={version}, a known-compromised "
                f"release ({reason}); pin an exact safe version"
            )
    return findings


def _allows(specifier: str, version: str) -> bool:
    """Whether a version range admits ``version``; True when that cannot be decided (no ``packaging``)."""
    if not specifier:
        return True
    try:
        from packaging.specifiers import InvalidSpecifier, SpecifierSet
    except ImportError:
        return True  # unprovable: refuse rather than guess
    try:
        return SpecifierSet(specifier).contains(version, prereleases=True)
    except InvalidSpecifier:
        return True


def check_file(path: Path, denied: DenyList, require_hashes: bool, seen: set[Path] | None = None) -> list[str]:
    seen = set() if seen is None else seen
    path = path.resolve()
    if path in seen:
        return []
    seen.add(path)
    findings = []
    for number, text in logical_lines(path):
        include = re.match(r"^(-r|-c|--requirement|--constraint)[\s=]+(\S+)", text)
        if include:
            findings += check_file(path.parent / include.group(2), denied, require_hashes, seen)
        elif not text.startswith("-"):  # other options (--index-url, --find-links, -e ...) name no release
            findings += check_requirement(text, f"{path.name}:{number}", denied, require_hashes)
    return findings


def check_installed(denied: DenyList) -> list[str]:
    from importlib.metadata import distributions

    findings = []
    for distribution in distributions():
        name = normalise_name(distribution.metadata["Name"] or "")
        version = normalise_version(distribution.version or "")
        if (name, version) in denied:
            findings.append(
                f"installed: {name}=={distribution.version} at {distribution.locate_file('')} is a known-compromised "
                f"release ({denied[(name, version)]}); uninstall it and rotate every credential this machine holds"
            )
    return findings


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", type=Path, help="requirements / lock files to check")
    parser.add_argument("--installed", action="store_true", help="also check this interpreter's distributions")
    parser.add_argument("--require-hashes", action="store_true", help="refuse requirements without --hash")
    parser.add_argument("--deny-list", type=Path, default=DEFAULT_DENY_LIST, help="name==version  # why, per line")
    args = parser.parse_args(argv)
    if not args.files and not args.installed:
        parser.error("give a requirements file or --installed")
    try:
        denied = load_deny_list(args.deny_list)
        findings = [finding for path in args.files for finding in check_file(path, denied, args.require_hashes)]
    except (OSError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.installed:
        findings += check_installed(denied)
    for finding in findings:
        print(f"error: {finding}", file=sys.stderr)
    checked = ", ".join([str(path) for path in args.files] + (["installed distributions"] if args.installed else []))
    if findings:
        print(f"refused: {len(findings)} problem(s) in {checked}", file=sys.stderr)
        return 1
    print(f"ok: {checked}: no release from {args.deny_list.name} ({len(denied)} entries)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
