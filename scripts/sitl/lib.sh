# Shared by scripts/sitl/ardupilot.sh and px4.sh (sourced, not run). Each script sets $cache first.

die() { echo "$(basename "$0"): $*" >&2; exit 2; }

# The autopilot tree to build: SOURCE itself when it is a folder, else a clone of the git URL
# SOURCE, with its submodules, kept under $cache/src. Prints its absolute path.
sitl_tree() {
  local source=$1
  if [[ -d $source ]]; then
    (cd "$source" && pwd)
    return
  fi
  local tree
  tree=$cache/src/$(basename "$source" .git)
  if [[ ! -d $tree/.git ]]; then
    mkdir -p "$cache/src"
    git clone --recurse-submodules "$source" "$tree" >&2
  fi
  echo "$tree"
}

# Checks run's vehicle count and first instance number; dies naming the bad one.
sitl_counts() {
  local n=$1 first=$2 first_name=$3
  [[ $n =~ ^[1-9][0-9]*$ ]] || die "run: N must be a positive integer, got '$n'"
  [[ $first =~ ^[0-9]+$ ]] || die "$first_name must be a non-negative integer, got '$first'"
}

# The command line of both scripts: build SOURCE, run [N], binary; anything else prints the usage,
# the script's header comment down to line $1.
sitl_main() {
  local usage_end=$1; shift
  case ${1:-} in
    build) shift; cmd_build "$@" ;;
    run) shift; cmd_run "$@" ;;
    binary) binary ;;
    *) sed -n "2,${usage_end}p" "$0" >&2; exit 2 ;;
  esac
}
