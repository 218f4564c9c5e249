"""PyYAML's libyaml loader and dumper where PyYAML has them (the venv's does), else its
pure-Python ones: the same documents, 4-6x faster. A grid collection's metadata holds its plan
(1,839 poses, 400 kB): the pure-Python loader took 9.9 s for it on a loaded machine (1.6 s with
libyaml), at the end of every goal, so a collection stopped by Ctrl-C could not end its goal
within spin.STOP_GRACE. Every node and command reads its cell file (12-20 ms each, twice for the
mock's simulation: part, with the pure-Python loader)."""
import yaml

LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


def compose_and_load(text: str):
    """(the document's node tree, with line marks; its data), None for an empty one, from
    one parse (yaml.compose and yaml.safe_load parse it twice). yaml.YAMLError if not YAML."""
    loader = LOADER(text)
    try:
        node = loader.get_single_node()
        return node, (None if node is None else loader.construct_document(node))
    finally:
        loader.dispose()
