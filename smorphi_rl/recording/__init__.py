"""Episodes recorded to MCAP with Foxglove's schemas, and read back for `replay`; the only package that imports
mcap: `messages` (topics, schemas, the messages of a step), `writer` (files, the env wrapper), `reader`.

`RecordingWrapper` wraps the env inside each env runner and writes every Nth episode of its env
instance to its own file (names carry the worker index and a random instance id, since RLlib's
sub-envs share one EnvContext). A file is written as NAME.mcap.part, flushed after the episode
start, every `flush_steps` steps and at the end, and renamed to NAME.mcap when finished: a file cut
short by a killed worker keeps every flushed chunk, and `read_episode` recovers them.
"""

from smorphi_rl.recording.messages import OUR_TOPICS, PART_SUFFIX, SUFFIX, RecordingError, step_record
from smorphi_rl.recording.reader import Episode, episode_files, read_episode
from smorphi_rl.recording.writer import EpisodeWriter, RecordingConfig, RecordingWrapper

__all__ = ["OUR_TOPICS", "PART_SUFFIX", "SUFFIX", "Episode", "EpisodeWriter", "RecordingConfig", "RecordingError",
           "RecordingWrapper", "episode_files", "read_episode", "step_record"]  # fmt: skip
