"""The default run's order (tests/conftest.py): the files named longest run first."""
import importlib.util
from pathlib import Path
from types import SimpleNamespace

REPO = Path(__file__).resolve().parents[1]
# by its path: the name "conftest" may stand for tests/blender's in a whole run
_spec = importlib.util.spec_from_file_location("tests_conftest", REPO / "tests" / "conftest.py")
conftest = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(conftest)


def test_the_longest_files_named_exist():
    # a file renamed or removed would drop out of the order without a word
    for name in conftest.LONGEST_FIRST:
        assert (REPO / name).is_file(), name


def test_the_longest_files_go_first_in_their_order_and_the_rest_keep_theirs():
    first, second = conftest.LONGEST_FIRST[0], conftest.LONGEST_FIRST[1]
    ids = ["tests/test_a.py::x", f"{second}::y", "tests/blender/test_b.py::z[1]",
           f"{first}::w", "tests/test_a.py::v", f"{second}::u"]
    items = [SimpleNamespace(nodeid=i) for i in ids]
    conftest.pytest_collection_modifyitems(None, None, items)
    assert [i.nodeid for i in items] == [f"{first}::w", f"{second}::y", f"{second}::u",
                                         "tests/test_a.py::x", "tests/blender/test_b.py::z[1]",
                                         "tests/test_a.py::v"]
