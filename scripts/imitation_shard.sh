#!/usr/bin/env bash
# Moved to scripts/imitation/imitation_shard.sh; this path forwards to it (shipped records' commands name it).
exec bash "$(dirname "$0")/imitation/imitation_shard.sh" "$@"
