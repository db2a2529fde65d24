//! Who may use the viewer. Every HTTP request and WebSocket upgrade must
//!
//! 1. name this server in its `Host` header: `localhost`, `127.0.0.1`, `[::1]`, the `--host`
//!    given or the address bound, with the port listened on (a server bound to every
//!    address, `0.0.0.0` or `::`, also takes any IP address literal). A page a web site
//!    loads under its own name re-pointed at 127.0.0.1 (DNS rebinding) names that site;
//! 2. when it says which page it comes from (`Origin`, sent by browsers on every WebSocket
//!    and script request), come from the viewer's own: `http://` and an address of rule 1,
//!    so a page on any other site or port cannot open the viewer's socket;
//! 3. carry the run's secret (`token=…` in the query), drawn from the operating system's
//!    random source when the server starts and printed in the address the command shows,
//!    as Jupyter does: another user of the machine, who can reach loopback and forge any
//!    header, cannot guess it. Compared in constant time.
//!
//! Anything else is refused with 403 and a line on stderr. Over `ssh -L`, the browser's
//! `Host` is `localhost:LOCAL`: the local port must be the server's (`ssh -L 8080:localhost:8080`).

use std::fmt;
use std::net::{IpAddr, SocketAddr};

use rand::TryRng as _;

use crate::model::error::{MAX_QUOTE, cut};
use crate::model::{Error, Result};

/// Bytes of the secret token (printed as twice as many hexadecimal digits).
const TOKEN_BYTES: usize = 16;

/// The rules of one server: its port, the host names it answers to and its token.
#[derive(Clone, Debug)]
pub struct Access {
    port: u16,
    /// Lower-case host names (IPv6 literals in brackets), without the port.
    names: Vec<String>,
    /// Bound to every address: any IP literal names this server.
    any_address: bool,
    token: String,
}

/// Why a request was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// No `Host`, several, or one that does not name this server.
    Host(String),
    /// An `Origin` that is not the viewer's own page (or several).
    Origin(String),
    /// No token, or not this run's.
    Token(&'static str),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::Host(why) => write!(f, "{why}"),
            Refusal::Origin(why) => write!(f, "{why}"),
            Refusal::Token(why) => write!(f, "{why}"),
        }
    }
}

/// A header value as quoted in a log line: at most [`MAX_QUOTE`] characters, control
/// characters escaped.
fn quote(value: &[u8]) -> String {
    let text: String = String::from_utf8_lossy(value).escape_debug().collect();
    cut(&text, MAX_QUOTE)
}

/// `name` as `Host` writes it: IPv6 literals in brackets, lower case.
fn host_name(name: &str) -> String {
    match name.parse::<IpAddr>() {
        Ok(IpAddr::V6(ip)) => format!("[{ip}]"),
        Ok(ip) => ip.to_string(),
        Err(_) => name.to_ascii_lowercase(),
    }
}

/// An authority `name[:port]` split in its name and port (`None`: no port given). `None`
/// when it is malformed.
fn split_authority(authority: &str) -> Option<(&str, Option<u16>)> {
    let (name, port) = if authority.starts_with('[') {
        let close = authority.find(']')?;
        let (name, rest) = authority.split_at(close + 1);
        match rest {
            "" => (name, None),
            _ => (name, Some(rest.strip_prefix(':')?)),
        }
    } else {
        match authority.rsplit_once(':') {
            Some((name, port)) => (name, Some(port)),
            None => (authority, None),
        }
    };
    let port = match port {
        None => None,
        Some(p) if !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()) => Some(p.parse().ok()?),
        Some(_) => return None,
    };
    (!name.is_empty()).then_some((name, port))
}

/// Whether `a` and `b` are equal, in a time that does not depend on where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let difference = a.iter().zip(b).fold(0_u8, |acc, (x, y)| acc | (x ^ y));
    std::hint::black_box(difference) == 0
}

/// The value of `key` in the query of a request target (`/path?a=1&key=v`).
fn query_value<'a>(target: &'a str, key: &str) -> Option<&'a str> {
    let (_, query) = target.split_once('?')?;
    query
        .split('&')
        .filter_map(|pair| pair.split_once('='))
        .find(|(k, _)| *k == key)
        .map(|(_, v)| v)
}

impl Access {
    /// The rules of a server asked to listen on `host` and bound to `addr`, with a fresh
    /// token from the operating system's random source.
    pub fn new(host: &str, addr: SocketAddr) -> Result<Access> {
        let mut bytes = [0_u8; TOKEN_BYTES];
        rand::rngs::SysRng.try_fill_bytes(&mut bytes).map_err(|e| {
            Error::usage(format!(
                "cannot draw the viewer's secret token from the operating system: {e}"
            ))
        })?;
        let token = bytes.iter().map(|b| format!("{b:02x}")).collect();
        Ok(Access::with_token(host, addr, token))
    }

    /// The rules with a given token (tests).
    #[must_use]
    pub fn with_token(host: &str, addr: SocketAddr, token: String) -> Access {
        let mut names: Vec<String> = ["localhost", "127.0.0.1", "[::1]"]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        for name in [host_name(host), host_name(&addr.ip().to_string())] {
            if !names.contains(&name) {
                names.push(name);
            }
        }
        Access {
            port: addr.port(),
            names,
            any_address: addr.ip().is_unspecified(),
            token,
        }
    }

    /// The run's secret, as the page's address carries it.
    #[must_use]
    pub fn token(&self) -> &str {
        &self.token
    }

    /// Whether `authority` (`name:port`) names this server.
    fn names_this_server(&self, authority: &str) -> bool {
        let Some((name, port)) = split_authority(authority) else {
            return false;
        };
        // No port: the scheme's, 80.
        if port.unwrap_or(80) != self.port {
            return false;
        }
        let name = name.to_ascii_lowercase();
        if self.names.contains(&name) {
            return true;
        }
        let literal = name
            .strip_prefix('[')
            .and_then(|n| n.strip_suffix(']'))
            .map_or_else(
                || name.parse::<std::net::Ipv4Addr>().is_ok(),
                |n| n.parse::<std::net::Ipv6Addr>().is_ok(),
            );
        self.any_address && literal
    }

    /// Checks a request: its `Host` values, its `Origin` values and its target (path and
    /// query). `Ok` when it may be served.
    pub fn check(&self, hosts: &[&[u8]], origins: &[&[u8]], target: &str) -> Result<(), Refusal> {
        let host = match hosts {
            [] => return Err(Refusal::Host("no `Host` header".into())),
            [host] => *host,
            _ => return Err(Refusal::Host("several `Host` headers".into())),
        };
        if !std::str::from_utf8(host).is_ok_and(|h| self.names_this_server(h.trim())) {
            return Err(Refusal::Host(format!(
                "`Host` \"{}\" is not this server's address (port {}; over `ssh -L`, forward the same local port)",
                quote(host),
                self.port
            )));
        }
        match origins {
            [] => {}
            [origin] => {
                let own = std::str::from_utf8(origin).ok().and_then(|o| {
                    let (scheme, rest) = o.trim().split_once("://")?;
                    scheme
                        .eq_ignore_ascii_case("http")
                        .then_some(rest)
                        .filter(|authority| self.names_this_server(authority))
                });
                if own.is_none() {
                    return Err(Refusal::Origin(format!(
                        "`Origin` \"{}\" is not the viewer's own page",
                        quote(origin)
                    )));
                }
            }
            _ => return Err(Refusal::Origin("several `Origin` headers".into())),
        }
        match query_value(target, "token") {
            None => Err(Refusal::Token(
                "no token (open the address the command printed, with its `?token=…`)",
            )),
            Some(token) if same_secret(token.as_bytes(), self.token.as_bytes()) => Ok(()),
            Some(_) => Err(Refusal::Token(
                "a wrong token (not this run's: open the address the command printed)",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn access(host: &str, addr: &str) -> Access {
        Access::with_token(host, addr.parse().unwrap(), "abc123".into())
    }

    #[test]
    fn hosts_origins_and_tokens_are_checked() {
        let a = access("127.0.0.1", "127.0.0.1:8080");
        let ok = |hosts: &[&str], origins: &[&str], target: &str| {
            let hosts: Vec<&[u8]> = hosts.iter().map(|h| h.as_bytes()).collect();
            let origins: Vec<&[u8]> = origins.iter().map(|h| h.as_bytes()).collect();
            a.check(&hosts, &origins, target)
        };
        for host in [
            "127.0.0.1:8080",
            "localhost:8080",
            "LOCALHOST:8080",
            "[::1]:8080",
        ] {
            assert_eq!(ok(&[host], &[], "/?token=abc123"), Ok(()), "{host}");
            let origin = format!("http://{host}");
            assert_eq!(
                ok(&[host], &[&origin], "/ws?token=abc123"),
                Ok(()),
                "{host}"
            );
        }
        for host in [
            "evil.example:8080",
            "127.0.0.1:8081",
            "127.0.0.1",
            "localhost.:8080",
            "127.0.0.1:+8080",
            "127.0.0.1:",
            "[::1:8080",
            "10.0.0.1:8080",
            "",
        ] {
            assert!(
                matches!(ok(&[host], &[], "/?token=abc123"), Err(Refusal::Host(_))),
                "{host}"
            );
        }
        assert!(matches!(
            ok(&[], &[], "/?token=abc123"),
            Err(Refusal::Host(_))
        ));
        let two = ["127.0.0.1:8080", "127.0.0.1:8080"];
        assert!(matches!(
            ok(&two, &[], "/?token=abc123"),
            Err(Refusal::Host(_))
        ));
        for origin in [
            "http://evil.example",
            "http://127.0.0.1:9999",
            "https://127.0.0.1:8080",
            "null",
            "http://127.0.0.1:8080.evil.example",
        ] {
            assert!(
                matches!(
                    ok(&["127.0.0.1:8080"], &[origin], "/ws?token=abc123"),
                    Err(Refusal::Origin(_))
                ),
                "{origin}"
            );
        }
        for target in [
            "/",
            "/?token=",
            "/?token=abc124",
            "/?token=abc1234",
            "/?x=abc123",
        ] {
            assert!(
                matches!(ok(&["127.0.0.1:8080"], &[], target), Err(Refusal::Token(_))),
                "{target}"
            );
        }
    }

    #[test]
    fn the_given_host_and_any_address_are_names_of_the_server() {
        let a = access("myhost.local", "192.168.1.5:80");
        let t = "/?token=abc123";
        assert_eq!(a.check(&[b"MyHost.local"], &[], t), Ok(()));
        assert_eq!(
            a.check(&[b"192.168.1.5"], &[b"http://192.168.1.5"], t),
            Ok(())
        );
        assert!(a.check(&[b"10.0.0.1"], &[], t).is_err());
        let any = access("0.0.0.0", "0.0.0.0:8080");
        assert_eq!(any.check(&[b"10.0.0.1:8080"], &[], t), Ok(()));
        assert_eq!(any.check(&[b"[fe80::1]:8080"], &[], t), Ok(()));
        assert!(any.check(&[b"evil.example:8080"], &[], t).is_err());
        let v6 = access("::1", "[::1]:8080");
        assert_eq!(v6.check(&[b"[::1]:8080"], &[], t), Ok(()));
    }

    #[test]
    fn a_long_header_is_quoted_cut() {
        let a = access("127.0.0.1", "127.0.0.1:8080");
        let host = format!("{}:8080", "x".repeat(100_000));
        let message = a
            .check(&[host.as_bytes()], &[], "/?token=abc123")
            .unwrap_err()
            .to_string();
        assert!(message.len() < 1000, "{} characters", message.len());
    }

    #[test]
    fn tokens_are_fresh_hex() {
        let addr = "127.0.0.1:1".parse().unwrap();
        let (a, b) = (
            Access::new("127.0.0.1", addr).unwrap(),
            Access::new("127.0.0.1", addr).unwrap(),
        );
        assert_eq!(a.token().len(), 2 * TOKEN_BYTES);
        assert!(a.token().bytes().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a.token(), b.token());
    }
}
