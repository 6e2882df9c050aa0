"""`umf ...` with every prompt's separation taking the shortest way apart (an experiment).

python results/umf-small-bandai-20261207/tried/eval_smallest.py eval --checkpoint M ...
"""

import sys

import umf.pipeline
import umf.separation
from umf.cli.main import run

push = umf.separation.separate_people


def shortest(joints, min_distance=umf.separation.MIN_DISTANCE,
             contact_distance=umf.separation.CONTACT_DISTANCE + umf.separation.FIT_MARGIN,
             smallest=False):  # fmt: skip
    return push(joints, min_distance, contact_distance, smallest=True)


umf.pipeline.separate_people = shortest
sys.argv = ["umf", *sys.argv[1:]]
run()
