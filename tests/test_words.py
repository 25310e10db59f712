"""Counts read as a reader says them."""

from smorphi_rl.words import counted, verb


def test_one_is_singular_and_every_other_count_plural():
    assert counted(1, "trial") == "1 trial"
    assert [counted(n, "env runner") for n in (0, 2)] == ["0 env runners", "2 env runners"]
    assert counted(1000, "CPU") == "1,000 CPUs" and counted(3, "policy", "policies") == "3 policies"


def test_the_verb_agrees_with_the_count():
    assert [verb(n, "needs", "need") for n in (0, 1, 2)] == ["need", "needs", "need"]
