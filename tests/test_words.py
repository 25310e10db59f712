"""Counts read as a reader says them."""

from smorphi_rl.words import counted


def test_one_is_singular_and_every_other_count_plural():
    assert counted(1, "trial") == "1 trial"
    assert [counted(n, "env runner") for n in (0, 2)] == ["0 env runners", "2 env runners"]
    assert counted(1000, "CPU") == "1,000 CPUs" and counted(3, "policy", "policies") == "3 policies"
