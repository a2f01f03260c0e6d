#!/bin/sh
# Install the Debian 12 packages gridsurvey needs, only those that are missing.
# Called by `make deps` (and so by `make`, `make check`, `make demo`); needs root to install.
set -eu
PKGS="gcc g++ make pkg-config sqlite3 libsqlite3-dev libfftw3-dev libsndfile1-dev libjansson-dev
libspng-dev nettle-dev liblapacke-dev libcsv-dev libtiff-dev
libplplot-dev plplot-driver-cairo libopenblas-dev libopencv-dev libgeographiclib-dev
geographiclib-tools groff-base libgpiod-dev gcc-avr avr-libc simavr libsimavr-dev libelf-dev gdal-bin
python3-gdal python3-numpy python3-pil python3-opencv clang libclang-rt-14-dev libgeos-dev
libpq-dev postgresql postgresql-15-postgis-3 strace"
# one dpkg-query for all of them (it runs before every build and demo)
# shellcheck disable=SC2086
installed=" $(dpkg-query -W -f='${Package} ${Status}\n' $PKGS 2>/dev/null | awk '$4 == "installed" { printf "%s ", $1 }')"
missing=""
for p in $PKGS; do
  case "$installed" in *" $p "*) ;; *) missing="$missing $p" ;; esac
done
[ -z "$missing" ] && exit 0
echo "deps: installing missing Debian packages:$missing"
if [ "$(id -u)" -ne 0 ]; then
  echo "deps: missing packages:$missing (run 'make deps' as root, or: sudo apt-get install$missing)" >&2
  exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# shellcheck disable=SC2086
apt-get install -y -qq $missing
