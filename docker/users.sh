#!/usr/bin/env bash
# Make the broker accounts of docker/mosquitto.acl: proxy, sim, operator, viewer.
#
#   bash docker/users.sh            # random passwords for the accounts that have none yet
#
# Writes docker/secrets/mosquitto.passwd (hashed, for mosquitto) and
# docker/secrets/<account> (the plain password, mode 600, handed to the
# services as compose secrets and read with --broker-password-file). Give an
# operator docker/secrets/operator; nothing here is ever committed
# (docker/secrets/ is git-ignored). Needs mosquitto_passwd (Debian: mosquitto).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
dir="${SECUAV_SECRETS_DIR:-$here/secrets}"  # SECUAV_SECRETS_DIR: elsewhere (the tests)
mkdir -p "$dir"
chmod 700 "$dir"
passwd_tool="$(command -v mosquitto_passwd || true)"
if [[ -z "$passwd_tool" ]]; then
    echo "users.sh: mosquitto_passwd not found (apt-get install mosquitto)" >&2
    exit 1
fi
umask 077
tmp="$(mktemp "$dir/passwd.XXXXXX")"
for account in proxy sim operator viewer; do
    if [[ ! -s "$dir/$account" ]]; then
        python3 -c 'import secrets; print(secrets.token_urlsafe(18))' > "$dir/$account"
        echo "users.sh: new password for $account in $dir/$account"
    fi
    "$passwd_tool" -b "$tmp" "$account" "$(cat "$dir/$account")"
done
# mosquitto (running as its own user in its container) reads the hashed file; the plain ones stay 600,
# owned by the uid the SecUAV image runs as (1000), since compose hands secrets over as bind mounts.
chmod 644 "$tmp"
if [[ $(id -u) == 0 ]]; then
    chown "${SECUAV_UID:-1000}:${SECUAV_UID:-1000}" "$dir"/proxy "$dir"/sim "$dir"/operator "$dir"/viewer
elif [[ $(id -u) != "${SECUAV_UID:-1000}" ]]; then
    echo "users.sh: run as root (or as uid ${SECUAV_UID:-1000}) so that the containers can read their password" >&2
fi
mv "$tmp" "$dir/mosquitto.passwd"
echo "users.sh: $dir/mosquitto.passwd has proxy, sim, operator, viewer"
