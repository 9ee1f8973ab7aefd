#!/usr/bin/env bash
# A Slurm job array that builds one dataset with N workers; each takes the shards k with k mod N = i
# (pointreggpt reads SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT). Resubmitting the same script after a
# preemption resumes: committed shards are skipped, half-written ones are redone.
#
#   sbatch --array=0-15 pipelines/slurm-build.sh pipelines/paper-3dmatch.toml /shared/datasets/prgpt
#   sbatch --array=0-15 pipelines/slurm-build.sh pipelines/paper-3dmatch.toml s3://my-bucket/prgpt   # no shared folder
#                                                              (credentials from AWS_* or AWS_PROFILE, exported before sbatch)
#
#SBATCH --job-name=pointreggpt-build
#SBATCH --cpus-per-task=8
#SBATCH --mem=8G
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --output=logs/%x-%A_%a.out
set -euo pipefail
CONFIG="${1:?usage: sbatch --array=0-(N-1) pipelines/slurm-build.sh <config.toml> <dataset dir> [--set k=v ...]}"
OUT="${2:?dataset folder}"
shift 2
exec ./target/release/pointreggpt --threads "${SLURM_CPUS_PER_TASK:-8}" build "$CONFIG" --out "$OUT" --no-progress "$@"
