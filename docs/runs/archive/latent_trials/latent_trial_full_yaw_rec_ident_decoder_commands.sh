set -o pipefail
P=.carry/trial_policy.npz; M="python -m mjxsysid.cli"
t() { local s=$SECONDS; "$@"; echo "[$(( SECONDS - s )) s] $*" >&2; }
t timeout 100 $M collect --single-latent --policy $P --out runs/s/data
t timeout 110 $M train-cfm --pairs runs/s/data --out runs/s/dec --policy $P --coords identifiable
t timeout 100 $M evaluate-decoder --decoders runs/s/dec --pairs runs/s/data --cases 1000 --samples 200 --policy $P
cp runs/s/dec/decoder_eval.json $OUT/trial_single_ident_eval.json
COORDS=identifiable CFM_DIR=runs/s/dec EPOCHS=100 t timeout 220 bash tools/seq_decoder_pipeline.sh runs/q --policy $P
cp runs/q/dec/decoder_eval.json $OUT/trial_seq_ident_eval.json
t timeout 60 $M collect --single-latent --out runs/s0/data
t timeout 80 $M train-cfm --pairs runs/s0/data --out runs/s0/dec --coords identifiable
t timeout 80 $M evaluate-decoder --decoders runs/s0/dec --pairs runs/s0/data --cases 1000 --samples 200
cp runs/s0/dec/decoder_eval.json $OUT/shipped_single_ident_eval.json
