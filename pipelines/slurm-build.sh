#!/usr/bin/env bash
# A Slurm job array that builds one dataset with N workers; each takes the shards k with k mod N = i
# (pointreggpt reads SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_MIN and SLURM_ARRAY_TASK_COUNT, so the array
# must be a plain range 0-(N-1) without a step). Resubmitting the same command after a preemption, a
# failure or an `scancel` resumes: committed shards are skipped, half-written ones are redone.
# Run it from the folder that holds the checkout (the binary is ./target/release/pointreggpt there, or
# set POINTREGGPT_BIN), with a dataset path every node sees:
#
#   sbatch --array=0-15 pipelines/slurm-build.sh pipelines/paper-3dmatch.toml /shared/datasets/prgpt
#   sbatch --array=0-15 pipelines/slurm-build.sh pipelines/paper-3dmatch.toml s3://my-bucket/prgpt   # no shared folder
#                                                              (credentials from AWS_* or AWS_PROFILE, exported before sbatch)
#   sbatch --array=0-3 --cpus-per-task=2 --mem=2G pipelines/slurm-build.sh pipelines/demo.toml /shared/demo
#   sbatch --array=0-15 --gres=gpu:1 pipelines/slurm-build.sh pipelines/paper-3dmatch.toml /shared/prgpt --device cuda
#                                                              (one GPU per task: Slurm sets each task's CUDA_VISIBLE_DEVICES,
#                                                               so `cuda` is that task's own GPU; needs a CUDA libtorch build)
#
# Resources: the #SBATCH lines below are defaults sized for the paper config (8 cores, 8 GB per task);
# options given on the sbatch command line override them (e.g. --cpus-per-task, --mem, --time,
# --partition, --output). The build uses as many threads as --cpus-per-task gives it.
# A job that asks more cores or memory than any node has stays pending (reason PartitionConfig).
#
# Logs: each task writes its build log to logs/<job name>-<array job id>_<task id>.out under the
# submission folder (POINTREGGPT_LOGS overrides it); the script creates that folder. Slurm opens its own
# --output file before the script runs, so that file cannot go into a folder the script creates (a
# missing folder makes every task fail without a word): it stays in the submission folder and holds only
# what happens before the log is opened, and Slurm's own notices (e.g. "CANCELLED").
#
#SBATCH --job-name=pointreggpt-build
#SBATCH --cpus-per-task=8
#SBATCH --mem=8G
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --output=slurm-%x-%A_%a.out
set -euo pipefail
LOGS="${POINTREGGPT_LOGS:-logs}"
mkdir -p "$LOGS"
exec >>"$LOGS/${SLURM_JOB_NAME:-pointreggpt-build}-${SLURM_ARRAY_JOB_ID:-${SLURM_JOB_ID:-local}}_${SLURM_ARRAY_TASK_ID:-0}.out" 2>&1
echo "task ${SLURM_ARRAY_TASK_ID:-0} of ${SLURM_ARRAY_TASK_COUNT:-1} on $(hostname), ${SLURM_CPUS_PER_TASK:-8} cpus, started $(date -u +%FT%TZ)"
CONFIG="${1:?usage: sbatch --array=0-(N-1) pipelines/slurm-build.sh <config.toml> <dataset dir or URL> [--set k=v ...]}"
OUT="${2:?usage: sbatch --array=0-(N-1) pipelines/slurm-build.sh <config.toml> <dataset dir or URL> [--set k=v ...]}"
shift 2
exec "${POINTREGGPT_BIN:-./target/release/pointreggpt}" --threads "${SLURM_CPUS_PER_TASK:-8}" build "$CONFIG" --out "$OUT" --no-progress "$@"
