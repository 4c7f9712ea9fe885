"""A process's bounded memo (stack.memo)."""

from stack.memo import Memo, file_version


def test_a_value_is_made_once_and_a_full_memo_starts_again():
    made = []
    memo = Memo(2)

    def make(k):
        return lambda: made.append(k) or k * 10

    assert [memo.get(k, make(k)) for k in (1, 2, 1, 2)] == [10, 20, 10, 20]
    assert made == [1, 2]
    assert memo.get(3, make(3)) == 30  # full: forgotten, then 3
    assert memo.get(1, make(1)) == 10 and made == [1, 2, 3, 1]


def test_a_rewritten_file_is_another_version(tmp_path):
    f = tmp_path / "task.yaml"
    f.write_text("a: 1\n")
    v = file_version(str(f))
    assert file_version(str(f)) == v
    f.write_text("a: 22\n")
    assert file_version(str(f)) != v
