//! Accepting connections: hyper's HTTP/1 server under the router, with the limits that
//! `axum::serve` leaves unset. A client gets [`HEADER_READ_TIMEOUT`] to send a request's head
//! (the connection is closed after it, so half-sent requests cannot pile up), a head of at most
//! [`MAX_HEADER_BYTES`] of headers, at most [`MAX_HEADERS`] of them, and a request target of at
//! most [`MAX_URI_BYTES`]. Every refusal is a problem document: hyper answers a request it cannot
//! parse (400, 414, 431) itself with an empty body, so [`ProblemHeads`] replaces those
//! answers on the wire.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::extract::Request;
use axum::http::StatusCode;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;

use crate::problem::Problem;

/// Time a client has to send a request's line and headers, from the connection's start or
/// the end of its previous response; then the connection is closed (no answer).
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);

/// Where a refusal sends a person: the limits and how to raise them.
const LIMITS_DOC: &str = "docs/http-api.md, \"Connection limits\"";

/// Most bytes of a request's headers (each `name: value` line), checked by the router; more:
/// 431.
pub const MAX_HEADER_BYTES: usize = 32 * 1024;

/// hyper's read buffer for a request head: a head that does not fit is refused by hyper
/// itself (431, or 414 for a request line over 64 KiB) before the router sees it.
pub const MAX_HEAD_BYTES: usize = 64 * 1024;

/// Most headers in a request; more: 431.
pub const MAX_HEADERS: usize = 100;

/// Longest request target (path and query), bytes; longer: 414.
pub const MAX_URI_BYTES: usize = 8 * 1024;

/// Serves `app` on `listener` until `shutdown` completes, then lets the requests under way
/// finish (no new connections are accepted) and returns.
pub async fn serve_connections(
    listener: TcpListener,
    app: Router,
    header_read_timeout: Duration,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> io::Result<()> {
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(header_read_timeout)
        .max_buf_size(MAX_HEAD_BYTES)
        .max_headers(MAX_HEADERS);
    // Each connection task holds a receiver: all are gone when every connection has closed.
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: wait for connections to close
                    // rather than spin.
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        tracing::trace!(%peer, "connection accepted");
        let conn =
            http.serve_connection(TokioIo::new(ProblemHeads::new(stream)), TowerToHyperService::new(app.clone()));
        let mut stop = stop_rx.clone();
        tokio::spawn(async move {
            let mut conn = std::pin::pin!(conn);
            let result = tokio::select! {
                r = conn.as_mut() => Some(r),
                _ = stop.wait_for(|s| *s) => None,
            };
            let result = match result {
                Some(r) => r,
                None => {
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
            };
            match result {
                Ok(()) => tracing::trace!(%peer, "connection closed"),
                Err(e) => tracing::debug!(%peer, "connection closed: {e}"),
            }
            drop(stop);
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    drop(stop_rx);
    stop_tx.closed().await;
    Ok(())
}

/// Middleware: 414 for a request target over [`MAX_URI_BYTES`], 431 for headers over
/// [`MAX_HEADER_BYTES`]; logs each request at debug level (the path only: a query may hold a
/// token).
pub async fn limit_and_log(req: Request, next: Next) -> Response {
    let (method, path) = (req.method().clone(), req.uri().path().to_string());
    let target = req.uri().path_and_query().map_or(0, |p| p.as_str().len());
    // As sent: `name: value\r\n` per header.
    let header_bytes: usize = req.headers().iter().map(|(k, v)| k.as_str().len() + v.len() + 4).sum();
    let mut response = if target > MAX_URI_BYTES {
        Problem::new(
            StatusCode::URI_TOO_LONG,
            format!("the request target has {target} bytes; at most {MAX_URI_BYTES} are allowed ({LIMITS_DOC})"),
        )
        .into_response()
    } else if header_bytes > MAX_HEADER_BYTES {
        Problem::new(
            StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            format!(
                "the request's headers have {header_bytes} bytes; at most {MAX_HEADER_BYTES} are allowed ({LIMITS_DOC})"
            ),
        )
        .into_response()
    } else {
        next.run(req).await
    };
    if matches!(response.status(), StatusCode::URI_TOO_LONG | StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE) {
        // As hyper does with the heads it refuses: a client that sends them is not kept.
        response.headers_mut().insert(axum::http::header::CONNECTION, axum::http::HeaderValue::from_static("close"));
    }
    tracing::debug!(%method, path = %truncated(&path, 200), status = response.status().as_u16(), "request");
    response
}

fn truncated(s: &str, max: usize) -> &str {
    match s.char_indices().nth(max) {
        Some((i, _)) => &s[..i],
        None => s,
    }
}

/// A connection whose empty-bodied 400, 414 and 431 answers — the ones hyper writes itself
/// when a request head does not parse or is over a limit — are replaced by the same answer
/// with a problem document. Every other byte passes through unchanged.
pub struct ProblemHeads<T> {
    inner: T,
    /// A replacement being written: its bytes, how many are written, and the length of the
    /// write it stands for (reported once all of it is out).
    pending: Option<(Vec<u8>, usize, usize)>,
}

impl<T> ProblemHeads<T> {
    /// Wraps a connection.
    pub fn new(inner: T) -> ProblemHeads<T> {
        ProblemHeads { inner, pending: None }
    }
}

/// hyper's own answer to a request it could not take (`HTTP/1.1 431 ...`, `content-length:
/// 0`, no content type, nothing after the head) as the same answer with a problem document,
/// or `None` for anything else.
pub fn problem_for_bare_head(head: &[u8]) -> Option<Vec<u8>> {
    let text = std::str::from_utf8(head).ok()?;
    let rest = text.strip_prefix("HTTP/1.1 ")?;
    let (status, detail) = match rest.get(..4)? {
        "400 " => {
            (StatusCode::BAD_REQUEST, "the request line or a header does not parse as HTTP/1.1 (RFC 9112)".to_string())
        }
        "414 " => (
            StatusCode::URI_TOO_LONG,
            format!("the request target is too long: at most {MAX_URI_BYTES} bytes ({LIMITS_DOC})"),
        ),
        "431 " => (
            StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            format!(
                "the request head is too large: at most {MAX_HEADERS} headers of at most {MAX_HEADER_BYTES} bytes \
                 in all, and a request target of at most {MAX_URI_BYTES} bytes ({LIMITS_DOC})"
            ),
        ),
        _ => return None,
    };
    // Only a whole head with an empty body: the buffer ends at the blank line.
    let headers = text.strip_suffix("\r\n\r\n")?;
    if headers.contains("\r\n\r\n") {
        return None;
    }
    let mut lines = headers.split("\r\n");
    let status_line = lines.next()?;
    let mut kept = Vec::new();
    let mut empty = false;
    for line in lines {
        let name = line.split(':').next().unwrap_or("").trim().to_ascii_lowercase();
        match name.as_str() {
            "content-length" => empty = line.split(':').nth(1).map(str::trim) == Some("0"),
            "content-type" | "transfer-encoding" => return None,
            "connection" => {}
            _ => kept.push(line),
        }
    }
    if !empty {
        return None;
    }
    let body = serde_json::to_vec(&Problem::new(status, detail)).ok()?;
    let mut out = format!("{status_line}\r\n");
    for line in kept {
        out.push_str(line);
        out.push_str("\r\n");
    }
    out.push_str(&format!(
        "content-type: {}\r\ncontent-length: {}\r\nconnection: close\r\n\r\n",
        crate::problem::PROBLEM_JSON,
        body.len()
    ));
    let mut out = out.into_bytes();
    out.extend_from_slice(&body);
    Some(out)
}

impl<T: AsyncRead + Unpin> AsyncRead for ProblemHeads<T> {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for ProblemHeads<T> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        let this = &mut *self;
        if this.pending.is_none() {
            match problem_for_bare_head(buf) {
                Some(replacement) => this.pending = Some((replacement, 0, buf.len())),
                None => return Pin::new(&mut this.inner).poll_write(cx, buf),
            }
        }
        // hyper repeats the same write until it is reported done.
        let (bytes, written, stands_for) = this.pending.as_mut().expect("a replacement");
        while *written < bytes.len() {
            match Pin::new(&mut this.inner).poll_write(cx, &bytes[*written..]) {
                Poll::Ready(Ok(0)) => {
                    this.pending = None;
                    return Poll::Ready(Err(io::ErrorKind::WriteZero.into()));
                }
                Poll::Ready(Ok(n)) => *written += n,
                Poll::Ready(Err(e)) => {
                    this.pending = None;
                    return Poll::Ready(Err(e));
                }
                Poll::Pending => return Poll::Pending,
            }
        }
        let n = *stands_for;
        this.pending = None;
        Poll::Ready(Ok(n))
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    // Not vectored: hyper then writes a head in one buffer, which the check above needs.
    fn is_write_vectored(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hyper_bare_error_heads_become_problem_documents() {
        let head = b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\ndate: Sat, 05 Dec 2026 07:00:00 GMT\r\n\r\n";
        let out = String::from_utf8(problem_for_bare_head(head).expect("replaced")).unwrap();
        let (h, body) = out.split_once("\r\n\r\n").unwrap();
        assert!(h.starts_with("HTTP/1.1 431 Request Header Fields Too Large\r\n"), "{h}");
        assert!(h.contains("\r\ndate: Sat, 05 Dec 2026 07:00:00 GMT"), "{h}");
        assert!(h.contains("\r\ncontent-type: application/problem+json"), "{h}");
        assert!(h.contains(&format!("\r\ncontent-length: {}", body.len())), "{h}");
        let p: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(p["status"], 431);
        assert!(p["detail"].as_str().unwrap().contains(&MAX_HEADER_BYTES.to_string()), "{p}");
    }

    #[test]
    fn other_answers_pass_unchanged() {
        // A handler's own answer (a content type or a body), another status, or a head with a
        // body after it is left alone.
        for head in [
            &b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: application/problem+json\r\ncontent-length: 0\r\n\r\n"[..],
            b"HTTP/1.1 404 Not Found\r\ncontent-length: 0\r\n\r\n",
            b"HTTP/1.1 400 Bad Request\r\ncontent-length: 2\r\n\r\n{}",
            b"HTTP/1.1 400 Bad Request\r\ncontent-length: 2\r\n\r\n",
            b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\n\r\n",
        ] {
            assert!(problem_for_bare_head(head).is_none(), "{}", String::from_utf8_lossy(head));
        }
    }
}
