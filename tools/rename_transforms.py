#!/usr/bin/env python3
"""Issue 39.3: one name per transform, applied to a tree (default: the repository).

    python3 tools/rename_transforms.py [ROOT]     # rewrites in place, prints the files changed

Word-bounded and idempotent: a second run changes nothing, so it can be run again on code
merged in later that still uses the old names. A line that contains ``legacy name`` is left
alone (the readers that still take the old cell keys, record keys and CLI option say so), and
so are test/data (files as users wrote them), build outputs and this file.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

# (pattern, replacement), in order; message fields are lower case (rosidl), the rest T_<from>_<to>
RULES: list[tuple[str, str]] = [
    # GetGroundTruth's fields, and their uses
    (r'\b(TransformStamped\s+|truth\.|response\.)tool_offset_true\b', r'\1t_flange_tool_true'),
    (r'\b(TransformStamped\s+|truth\.|response\.)hand_eye_true\b', r'\1t_flange_optical_true'),
    (r'\btool_offset_true\b', 'T_flange_tool_true'),
    (r'\btrue_tool_offset\b', 'T_flange_tool_true'),
    (r'\btool_offset\b', 'T_flange_tool'),
    (r'\bcoupling_offset\b', 'T_flange_coupling'),
    (r'\bcoupling_offset_true\b', 'p_flange_coupling_true'),   # a position only
    (r'\bcoupling_offset_xyz\b', 'p_flange_coupling'),
    (r'\bT_flange_tcp\b', 'T_flange_tool'),
    (r'\bR_flange_tcp\b', 'R_flange_tool'),
    (r'\bt_flange_tcp\b', 't_flange_tool'),
    (r'\bT_FLANGE_TCP\b', 'T_FLANGE_TOOL'),
    (r'\btool_xyz0\b', 'p_flange_tool0'),
    (r'\btool_xyz\b', 'p_flange_tool'),
    (r'--tool-offset\b', '--t-flange-tool'),
    # the camera's cell keys (a YAML key only: 'hand_eye' is also the calibration's kind)
    (r'^(\s*)hand_eye_true:', r'\1T_flange_optical_true:'),
    (r'^(\s*)hand_eye:(\s*(#.*)?$|\s*\{\s*xyz)', r'\1T_flange_optical:\2'),
    (r"'camera', 'hand_eye_true'", "'camera', 'T_flange_optical_true'"),
    (r"'camera', 'hand_eye'", "'camera', 'T_flange_optical'"),
    (r"\*keys, 'hand_eye_true'", "*keys, 'T_flange_optical_true'"),
    (r"'camera': \{'frame_id': None, 'hand_eye': ", "'camera': {'frame_id': None, 'T_flange_optical': "),
]
SUFFIXES = {'.py', '.yaml', '.yml', '.md', '.msg', '.srv', '.action', '.sh', '.txt', '.cfg'}
SKIP_DIRS = {'.git', '.venv', 'build', 'install', 'log', '__pycache__', 'interfaces'}
MARKER = 'legacy name'
COMPILED = [(re.compile(p, re.MULTILINE), r) for p, r in RULES]
COMMENT = re.compile(r'(?<=\S)( {2,})#')   # an inline comment after two or more spaces


def _keep_comment_column(old: str, new: str) -> str:
    """``new`` with its inline comment moved back to ``old``'s column where the spaces allow."""
    was, now = COMMENT.search(old), COMMENT.search(new)
    if not was or not now or was.end() == now.end():
        return new
    spaces = max(1, len(now.group(1)) + was.end() - now.end())
    return new[:now.start()] + ' ' * spaces + new[now.end() - 1:]


def rename(text: str) -> str:
    """``text`` with the new names, lines holding MARKER unchanged."""
    lines = text.splitlines(keepends=True)
    for i, line in enumerate(lines):
        if MARKER in line:
            continue
        new = line
        for pattern, replacement in COMPILED:
            new = pattern.sub(replacement, new)
        lines[i] = line if new == line else _keep_comment_column(line, new)
    return ''.join(lines)


def files(root: Path):
    for path in sorted(root.rglob('*')):
        rel = path.relative_to(root)
        if (path.is_file() and path.suffix in SUFFIXES and not SKIP_DIRS & set(rel.parts)
                and rel.parts[:2] != ('test', 'data') and path.resolve() != Path(__file__).resolve()):
            yield path


def main(root: Path) -> None:
    for path in files(root):
        text = path.read_text(encoding='utf-8')
        new = rename(text)
        if new != text:
            path.write_text(new, encoding='utf-8')
            print(path.relative_to(root))


if __name__ == '__main__':
    main(Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1]))
