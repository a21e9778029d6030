//! Who may reach `cellcal serve`: the exposure rule for the listen address, the accepted
//! tokens (configured, or a one-time operator token on loopback), and the API gate.

use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::anyhow;

use cellcal::api::{Gate, Scheme};
use cellcal::auth::{new_token, Role, TokenDigest, TokenTable};
use cellcal::config::ApiSection;

use crate::{input, other, Failure};

/// Refuse a non-loopback `addr` without configured tokens (exit 2); warn on stderr when it
/// would carry tokens over plain HTTP.
pub fn check_exposure(addr: SocketAddr, api: &ApiSection) -> Result<(), Failure> {
    if addr.ip().is_loopback() {
        return Ok(());
    }
    if api.tokens.is_empty() {
        return Err(input(anyhow!(
            "--listen {addr} is reachable from other machines, but the configuration has no [[api.tokens]]: \
             make one with `cellcal token --name NAME --role operator` and paste its entry, or listen on 127.0.0.1"
        )));
    }
    if api.tls.is_none() {
        tracing::warn!(
            "serving plain HTTP on {addr}: tokens and commands cross the network unencrypted; \
             set [api] tls_cert and tls_key"
        );
    }
    Ok(())
}

/// The configured tokens; with none, a new one-time operator token, returned to be shown once.
pub fn accepted_tokens(api: &ApiSection) -> Result<(TokenTable, Option<String>), Failure> {
    let mut table = TokenTable::default();
    for t in &api.tokens {
        table.add(t.digest.clone(), &t.name, t.role);
    }
    if !table.is_empty() {
        return Ok((table, None));
    }
    let token = new_token().map_err(other)?;
    table.add(TokenDigest::of_token(&token), "one-time", Role::Operator);
    Ok((table, Some(token)))
}

/// The API gate of a daemon serving `scheme` on `bound` with `tokens` and `[api]`'s extras.
pub fn gate(tokens: TokenTable, scheme: Scheme, bound: SocketAddr, api: &ApiSection) -> Arc<Gate> {
    Arc::new(Gate::new(
        tokens,
        scheme,
        bound,
        &api.allowed_hosts,
        &api.allowed_origins,
    ))
}
