#!/usr/bin/env bash
# One prepared device run (#64 item 7): gpu_check under three XLA command-buffer
# settings, and a cold `stickslip identify` of the bundled fixtures on the GPU.
# Usage on the lent machine: OUT=... bash benchmarks/gpu_session.sh
export PYTHONUNBUFFERED=1 PYTHONPATH=.
LOG=$OUT/session.log
{ nvidia-smi -L; python3 -c "import jax,equinox,diffrax,optimistix,numpy;print('jax',jax.__version__,'eqx',equinox.__version__,'diffrax',diffrax.__version__,'optx',optimistix.__version__,'numpy',numpy.__version__)"; } >>"$LOG" 2>&1
run_check() {  # tag, XLA_FLAGS
  mkdir -p "$OUT/$1"
  echo "== gpu_check $1 ($2)" >>"$LOG"
  /usr/bin/time -f "wall %e s" env OUT="$OUT/$1" XLA_FLAGS="$2" GPU_CHECK_DURATION=0.02 \
    timeout 150 python3 benchmarks/gpu_check.py >>"$LOG" 2>&1
  echo "rc $?" >>"$LOG"
}
run_check default ""
echo "== identify fixtures (cold)" >>"$LOG"
/usr/bin/time -f "wall %e s" timeout 200 python3 stickslip_cli.py \
  identify fixtures/identification --out /tmp/id --fix Ms=0.0247 >>"$LOG" 2>&1
echo "rc $?" >>"$LOG"
cp /tmp/id/fit.json "$OUT/identify_fit.json" 2>/dev/null
run_check while "--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,CONDITIONAL,WHILE --xla_gpu_graph_min_graph_size=1"
run_check off "--xla_gpu_enable_command_buffer="
