//! The viewer's server: a TCP listener that answers plain `GET`s with the page's assets
//! (compiled into the binary: no CDN, works offline) and upgrades `/ws` to a WebSocket, one
//! per page. Every request first passes [`Access`]: its `Host` names this server, its
//! `Origin` (when a browser sends one) is the viewer's own page, and it carries the run's
//! secret token, which the address the command prints holds; anything else is answered 403
//! and logged on stderr.
//!
//! Connections are bounded: at most [`MAX_CONNECTIONS`] at once, each served on its own
//! thread (a page's WebSocket has a second, small one, blocked reading the socket); one
//! more, or one the operating system refuses a thread, is answered 503 and closed. A page's
//! thread sleeps on one channel that both its socket's reader and the render thread feed:
//! an idle page costs no CPU, and a finished frame is sent the moment it is made. The
//! listener waits in `accept` (on Linux; it is polled elsewhere), looking at the stop flag
//! four times a second, and on stopping wakes every page's thread.
//! HTTP request heads are parsed by `httparse`, WebSocket frames by `tungstenite`.

use std::collections::{HashMap, VecDeque};
use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, SyncSender, channel, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tungstenite::protocol::Role;
use tungstenite::{Message, WebSocket};

use crate::model::error::{MAX_QUOTE, cut};
use crate::model::{Error, Result};
use crate::scenes::paths::{Lens, framing_circle, orbit, time_range};
use crate::view::Showing;
use crate::view::access::Access;
use crate::view::protocol::{Request, pack, parse_request};
use crate::view::render_thread::{Job, Output, Queue, Reply, spawn};

const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const STYLE_CSS: &str = include_str!("page/style.css");

/// Most connections served at once (pages' WebSockets and requests for assets together);
/// the next is answered 503.
pub const MAX_CONNECTIONS: usize = 128;
/// Largest HTTP request head read, bytes.
const MAX_HEAD: usize = 16 * 1024;
/// How long a connection may take to send its request head.
const HEAD_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a write may wait for a page that does not read.
const WRITE_TIMEOUT: Duration = Duration::from_secs(10);
/// Largest WebSocket message a page may send, bytes (a long keyframe list fits).
const MAX_MESSAGE: usize = 4 << 20;
/// How long the listener waits in `accept` before looking at the stop flag.
const STOP_CHECK: Duration = Duration::from_millis(250);
/// How often the listener looks for new connections where it cannot wait in `accept`, or
/// after `accept` failed (out of descriptors).
const ACCEPT_POLL: Duration = Duration::from_millis(20);
/// How often a running fit's progress is sent to its pages.
const LIVE_EVERY: Duration = Duration::from_millis(500);
/// Bytes a socket's reader takes in one read, and how many such chunks may wait for the
/// page's thread (the reader stops reading beyond: memory stays bounded).
const READ_CHUNK: usize = 16 * 1024;
const READ_CHUNKS_WAITING: usize = 8;
/// Stack of a socket's reader thread (it only moves bytes).
const READER_STACK: usize = 64 * 1024;
/// Most refusals logged per second (a page hammering the server does not flood stderr).
const LOG_LINES_PER_SECOND: u32 = 20;

/// A bound listener, not yet serving.
pub struct Server {
    listener: TcpListener,
    addr: SocketAddr,
    access: Arc<Access>,
}

impl Server {
    /// Listens on `host:port` (port 0: any free port), with a fresh secret token. A port in
    /// use is a usage error naming it.
    pub fn bind(host: &str, port: u16) -> Result<Server> {
        let addr = (host, port)
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .ok_or_else(|| {
                Error::usage(format!("host `{host}` is not an address of this machine"))
            })?;
        let listener = TcpListener::bind(addr).map_err(|e| {
            if e.kind() == std::io::ErrorKind::AddrInUse {
                Error::usage(format!(
                    "port {port} is in use on {host}: choose another port"
                ))
            } else {
                Error::usage(format!("cannot listen on {host} port {port}: {e}"))
            }
        })?;
        let addr = listener
            .local_addr()
            .map_err(|e| Error::usage(format!("cannot listen on {host} port {port}: {e}")))?;
        let access = Arc::new(Access::new(host, addr)?);
        Ok(Server {
            listener,
            addr,
            access,
        })
    }

    /// The page's address, with the run's token.
    #[must_use]
    pub fn url(&self) -> String {
        format!("http://{}/?token={}", self.addr, self.access.token())
    }

    /// Serves `showing` until `stop` is set; then ends the render thread and every page's
    /// connection.
    pub fn run(self, showing: &Showing, stop: &Arc<AtomicBool>) -> Result<()> {
        let waits = wait_in_accept(&self.listener);
        self.listener
            .set_nonblocking(!waits)
            .map_err(|e| Error::usage(format!("cannot serve: {e}")))?;
        let shared = Arc::new(Shared {
            queue: spawn(showing.clone())?,
            hello: hello(showing).to_string(),
            index_html: INDEX_HTML.replace("{{token}}", self.access.token()),
            showing: showing.clone(),
            stop: Arc::clone(stop),
            access: Arc::clone(&self.access),
            log: Log::default(),
            open: AtomicUsize::new(0),
            pages: Mutex::new(HashMap::new()),
        });
        let mut next_id = 0;
        while !stop.load(Ordering::Relaxed) {
            match self.listener.accept() {
                Ok((stream, peer)) => {
                    admit(&shared, stream, peer, next_id);
                    next_id += 1;
                }
                // The wait for a connection ended: look at the stop flag.
                Err(e)
                    if waits
                        && matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock
                                | std::io::ErrorKind::TimedOut
                                | std::io::ErrorKind::Interrupted
                        ) => {}
                // Nothing to accept (polled), or the process is out of descriptors: wait a
                // little.
                Err(_) => std::thread::sleep(ACCEPT_POLL),
            }
        }
        shared.queue.stop();
        for page in shared.lock_pages().values() {
            let _ = page.send(Event::Stop);
        }
        Ok(())
    }
}

/// What every connection's thread shares.
struct Shared {
    queue: Arc<Queue>,
    hello: String,
    /// The page, its assets' addresses carrying the token.
    index_html: String,
    showing: Showing,
    stop: Arc<AtomicBool>,
    access: Arc<Access>,
    log: Log,
    /// Connections being served.
    open: AtomicUsize,
    /// How to wake each page's thread (the server stops).
    pages: Mutex<HashMap<u64, Sender<Event>>>,
}

impl Shared {
    fn lock_pages(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Sender<Event>>> {
        self.pages
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// Makes `accept` on `listener` wait at most [`STOP_CHECK`] for a connection (Linux honours
/// a listening socket's receive timeout in `accept`). `false` where it cannot: the listener
/// is then polled.
#[cfg(target_os = "linux")]
fn wait_in_accept(listener: &TcpListener) -> bool {
    use std::os::fd::AsRawFd as _;
    let timeout = libc::timeval {
        tv_sec: 0,
        tv_usec: libc::suseconds_t::try_from(STOP_CHECK.as_micros()).unwrap_or(250_000),
    };
    // SAFETY: `setsockopt` reads `size_of::<timeval>()` bytes from `timeout`, a valid
    // `timeval` that outlives the call, on the listener's open descriptor.
    let set = unsafe {
        libc::setsockopt(
            listener.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_RCVTIMEO,
            (&raw const timeout).cast(),
            std::mem::size_of::<libc::timeval>() as libc::socklen_t,
        )
    };
    set == 0
}

#[cfg(not(target_os = "linux"))]
fn wait_in_accept(_: &TcpListener) -> bool {
    false
}

/// A connection's place among the [`MAX_CONNECTIONS`]; given back when dropped.
struct Slot(Arc<Shared>);

impl Slot {
    fn claim(shared: &Arc<Shared>) -> Option<Slot> {
        shared
            .open
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < MAX_CONNECTIONS).then_some(n + 1)
            })
            .ok()
            .map(|_| Slot(Arc::clone(shared)))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.open.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Serves a new connection on a thread of its own, or answers 503 when there are already
/// [`MAX_CONNECTIONS`] or the operating system refuses a thread.
fn admit(shared: &Arc<Shared>, stream: TcpStream, peer: SocketAddr, id: u64) {
    let Some(slot) = Slot::claim(shared) else {
        let why = format!("{MAX_CONNECTIONS} connections are open, the most served at once");
        shared.log.refused(peer, "a connection", &why, 503);
        busy(stream);
        return;
    };
    let (hand, handed) = channel::<TcpStream>();
    let page = Page {
        id,
        peer,
        shared: Arc::clone(shared),
    };
    let spawned = std::thread::Builder::new()
        .name("splat4d-view-page".into())
        .spawn(move || {
            let _slot = slot;
            if let Ok(stream) = handed.recv() {
                page.serve(stream);
            }
        });
    match spawned {
        Ok(_) => {
            // The thread holds the receiver until it has the stream.
            let _ = hand.send(stream);
        }
        Err(e) => {
            let why = format!("no thread for it ({e})");
            shared.log.refused(peer, "a connection", &why, 503);
            busy(stream);
        }
    }
}

/// Answers 503 and closes, without ever blocking the listener.
fn busy(mut stream: TcpStream) {
    let body = b"the viewer is serving as many connections as it can: try again later\n";
    let head = format!(
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let _ = stream.set_nonblocking(true);
    let _ = stream.write_all(&[head.as_bytes(), body].concat());
    let _ = stream.shutdown(Shutdown::Write);
}

/// The refusals' lines on stderr, at most [`LOG_LINES_PER_SECOND`]; the lines held back are
/// counted in the next one.
#[derive(Default)]
struct Log {
    state: Mutex<LogState>,
}

#[derive(Default)]
struct LogState {
    window: Option<Instant>,
    lines: u32,
    held_back: u64,
}

impl Log {
    fn refused(&self, peer: SocketAddr, what: &str, why: &str, status: u16) {
        let mut state = self
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let now = Instant::now();
        if state
            .window
            .is_none_or(|w| now.duration_since(w) >= Duration::from_secs(1))
        {
            state.window = Some(now);
            state.lines = 0;
        }
        if state.lines >= LOG_LINES_PER_SECOND {
            state.held_back += 1;
            return;
        }
        state.lines += 1;
        let held_back = std::mem::take(&mut state.held_back);
        let more = if held_back > 0 {
            format!(" ({held_back} more refused before, not shown)")
        } else {
            String::new()
        };
        eprintln!("splat4d view: refused {what} from {peer} with {status}: {why}{more}");
    }
}

/// Vertical field of view of the first view, degrees.
const START_FOV: f64 = 40.0;

/// The first view: the framing orbit's first camera ([`framing_circle`]) at the start of the
/// time range, as an OpenGL camera-to-world matrix, and the framing circle.
fn start_view(showing: &Showing) -> (Option<[[f64; 4]; 4]>, crate::scenes::paths::Circle) {
    let scene = &showing.scene;
    let [t0, t1] = time_range(scene);
    let lens = Lens {
        width: 512,
        height: 512,
        fov_y_degrees: START_FOV,
    };
    let circle = framing_circle(
        scene,
        &[t0, crate::scenes::paths::lerp(t0, t1, 0.5), t1],
        showing.options.cutoff,
        &lens,
        scene.up.unwrap_or_default(),
    );
    let pose = orbit(&circle, &lens, t0)
        .ok()
        .and_then(|frames| frames.first().map(|f| f.camera.opengl_camera_to_world()));
    (pose, circle)
}

/// The `hello` message: the scene's facts, a framing camera, the dataset's views.
fn hello(showing: &Showing) -> serde_json::Value {
    let scene = &showing.scene;
    let [t0, t1] = time_range(scene);
    let up = scene.up.unwrap_or_default();
    let (pose, circle) = start_view(showing);
    let flat = |m: [[f64; 4]; 4]| m.iter().flatten().copied().collect::<Vec<f64>>();
    let fov =
        |c: &crate::model::Camera| (2.0 * (0.5 * f64::from(c.height) / c.fy).atan()).to_degrees();
    let views: Vec<serde_json::Value> = showing
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            serde_json::json!({
                "index": i, "name": v.name, "time": v.time,
                "width": v.camera.width, "height": v.camera.height,
                "c2w": flat(v.camera.opengl_camera_to_world()), "fov": fov(&v.camera),
            })
        })
        .collect();
    serde_json::json!({
        "type": "hello",
        "title": showing.title,
        "scene": {
            "kernels": scene.len(),
            "blend": scene.blend.to_string(),
            "time_range": [t0, t1],
            "centre": circle.centre,
            "distance": circle.radius,
            "up": up.basis().0,
        },
        "camera": pose.map(|m| serde_json::json!({"c2w": flat(m), "fov": START_FOV})),
        "views": views,
        "live": showing.live.is_some(),
        "max_side": crate::view::MAX_SIDE,
    })
}

/// One connection's share of the server.
struct Page {
    id: u64,
    peer: SocketAddr,
    shared: Arc<Shared>,
}

/// What wakes a page's thread.
enum Event {
    /// Bytes from the page's socket.
    Bytes(Vec<u8>),
    /// The page closed its socket (or it failed).
    Closed,
    /// A job of the page's is done.
    Output(Output),
    /// The server stops.
    Stop,
}

/// The WebSocket's stream: reads what the socket's reader handed over (`WouldBlock` when
/// that is all read), writes to the socket.
struct Pipe {
    inbox: VecDeque<u8>,
    stream: TcpStream,
}

impl Read for Pipe {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.inbox.is_empty() && !buf.is_empty() {
            return Err(std::io::ErrorKind::WouldBlock.into());
        }
        self.inbox.read(buf)
    }
}

impl Write for Pipe {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.stream.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// Reads a request head (up to the blank line), at most [`MAX_HEAD`] bytes, and whatever
/// followed it in the same reads.
fn read_head(stream: &mut TcpStream) -> Option<Vec<u8>> {
    let mut head = Vec::new();
    let mut buf = [0_u8; 2048];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = stream.read(&mut buf).ok().filter(|&n| n > 0)?;
        head.extend_from_slice(&buf[..n]);
        if head.len() > MAX_HEAD {
            return None;
        }
    }
    Some(head)
}

/// The static asset at `path` (no query): content type and body.
fn asset(path: &str) -> Option<(&'static str, &'static str)> {
    match path {
        "/app.js" => Some(("text/javascript; charset=utf-8", APP_JS)),
        "/style.css" => Some(("text/css; charset=utf-8", STYLE_CSS)),
        _ => None,
    }
}

fn respond(stream: &mut TcpStream, status: &str, kind: &str, body: &[u8]) {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nReferrer-Policy: no-referrer\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let _ = stream.write_all(head.as_bytes());
    let _ = stream.write_all(body);
    let _ = stream.flush();
}

/// The values of the headers named `name`.
fn header_values<'h>(headers: &[httparse::Header<'h>], name: &str) -> Vec<&'h [u8]> {
    headers
        .iter()
        .filter(|h| h.name.eq_ignore_ascii_case(name))
        .map(|h| h.value)
        .collect()
}

/// Whether a header's comma-separated values hold `token` (case-insensitive).
fn lists(headers: &[httparse::Header<'_>], name: &str, token: &str) -> bool {
    header_values(headers, name).iter().any(|v| {
        String::from_utf8_lossy(v)
            .split(',')
            .any(|part| part.trim().eq_ignore_ascii_case(token))
    })
}

impl Page {
    /// Answers one connection: an asset, or a page's WebSocket until it closes.
    fn serve(self, mut stream: TcpStream) {
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        let _ = stream.set_read_timeout(Some(HEAD_TIMEOUT));
        let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
        let Some(head) = read_head(&mut stream) else {
            return;
        };
        let mut headers = [httparse::EMPTY_HEADER; 64];
        let mut request = httparse::Request::new(&mut headers);
        let Ok(httparse::Status::Complete(used)) = request.parse(&head) else {
            respond(&mut stream, "400 Bad Request", "text/plain", b"bad request");
            return;
        };
        let target = request.path.unwrap_or("");
        let path = target.split('?').next().unwrap_or("");
        let method = request.method.unwrap_or("");
        if let Err(refusal) = self.shared.access.check(
            &header_values(request.headers, "host"),
            &header_values(request.headers, "origin"),
            target,
        ) {
            let what = cut(
                &format!("{method} {path}").escape_debug().to_string(),
                MAX_QUOTE,
            );
            self.shared
                .log
                .refused(self.peer, &what, &refusal.to_string(), 403);
            let body = format!("forbidden: {refusal}\n");
            respond(
                &mut stream,
                "403 Forbidden",
                "text/plain; charset=utf-8",
                body.as_bytes(),
            );
            return;
        }
        if method != "GET" {
            respond(
                &mut stream,
                "405 Method Not Allowed",
                "text/plain",
                b"GET only",
            );
            return;
        }
        let upgrade = lists(request.headers, "upgrade", "websocket");
        match path {
            "/ws" if upgrade => {
                let key = header_values(request.headers, "sec-websocket-key");
                let version = header_values(request.headers, "sec-websocket-version");
                match (key.as_slice(), version.as_slice()) {
                    ([key], [b"13"]) => {
                        let (key, rest) = (key.to_vec(), head[used..].to_vec());
                        self.websocket(stream, &key, rest);
                    }
                    _ => respond(
                        &mut stream,
                        "400 Bad Request",
                        "text/plain",
                        b"a WebSocket upgrade needs one Sec-WebSocket-Key and version 13",
                    ),
                }
            }
            "/" | "/index.html" => respond(
                &mut stream,
                "200 OK",
                "text/html; charset=utf-8",
                self.shared.index_html.as_bytes(),
            ),
            "/first.jpg" => match self.first_frame(target) {
                Some(jpeg) => respond(&mut stream, "200 OK", "image/jpeg", &jpeg),
                None => respond(
                    &mut stream,
                    "503 Service Unavailable",
                    "text/plain",
                    b"no frame",
                ),
            },
            _ => match asset(path) {
                Some((kind, body)) => respond(&mut stream, "200 OK", kind, body.as_bytes()),
                None => respond(&mut stream, "404 Not Found", "text/plain", b"not found"),
            },
        }
    }

    /// The first frame as a JPEG, `GET /first.jpg?width=W&height=H` (sides clamped to
    /// [`crate::view::MAX_SIDE`]): the start view at the start time. The page loads it as an
    /// image, so the page's load (and a screenshot taken then) waits for a drawn scene.
    fn first_frame(&self, target: &str) -> Option<Vec<u8>> {
        let query = target.split_once('?').map_or("", |(_, q)| q);
        let side = |key: &str, default: u32| {
            query
                .split('&')
                .filter_map(|pair| pair.split_once('='))
                .find(|(k, _)| *k == key)
                .and_then(|(_, v)| v.parse::<u32>().ok())
                .unwrap_or(default)
                .clamp(1, crate::view::MAX_SIDE)
        };
        let (width, height) = (side("width", 800), side("height", 600));
        let showing = &self.shared.showing;
        let camera = crate::model::Camera::from_opengl_camera_to_world(
            width,
            height,
            crate::model::Camera::centred_intrinsics(width, height, START_FOV.to_radians()),
            start_view(showing).0?,
        )
        .ok()?;
        let (reply, frames) = channel();
        let job = Job::Frame {
            id: 0,
            camera: Box::new(camera),
            time: time_range(&showing.scene)[0],
            lossless: false,
        };
        let reply: Reply = Box::new(move |output| {
            let _ = reply.send(output);
        });
        self.shared.queue.submit(2 * self.id, job, reply);
        match frames.recv_timeout(Duration::from_secs(60)).ok()? {
            Output::Frame { image, .. } => Some(image.encode(false).0),
            _ => None,
        }
    }

    /// The WebSocket of one page: answers the upgrade (`key`: its `Sec-WebSocket-Key`,
    /// `rest`: bytes that came after the request head), then requests in, frames and answers
    /// out until the page leaves or the server stops.
    fn websocket(self, mut stream: TcpStream, key: &[u8], rest: Vec<u8>) {
        // The socket's reader first: without a thread for it, the upgrade is answered 503.
        // It waits on the socket as long as the page stays.
        let _ = stream.set_read_timeout(None);
        let (events_in, events) = channel();
        let (credits_in, credits) = sync_channel(READ_CHUNKS_WAITING);
        for _ in 0..READ_CHUNKS_WAITING {
            let _ = credits_in.try_send(());
        }
        let feed = events_in.clone();
        let reader = stream.try_clone().and_then(|reading| {
            std::thread::Builder::new()
                .name("splat4d-view-socket".into())
                .stack_size(READER_STACK)
                .spawn(move || read_socket(reading, &feed, &credits))
        });
        if let Err(e) = reader {
            let why = format!("no thread to read its socket ({e})");
            self.shared.log.refused(self.peer, "a WebSocket", &why, 503);
            respond(
                &mut stream,
                "503 Service Unavailable",
                "text/plain",
                b"the viewer cannot serve another page now: try again later",
            );
            return;
        }
        let accept = tungstenite::handshake::derive_accept_key(key);
        let response = format!(
            "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n\r\n"
        );
        let config = tungstenite::protocol::WebSocketConfig::default()
            .read_buffer_size(READ_CHUNK)
            .max_message_size(Some(MAX_MESSAGE))
            .max_frame_size(Some(MAX_MESSAGE));
        let upgraded = stream.write_all(response.as_bytes()).is_ok();
        let pipe = Pipe {
            inbox: rest.into(),
            stream,
        };
        let mut ws = WebSocket::from_raw_socket(pipe, Role::Server, Some(config));
        if upgraded {
            self.shared.lock_pages().insert(self.id, events_in.clone());
            if ws.send(Message::text(self.shared.hello.as_str())).is_ok()
                && self.take_messages(&mut ws, &events_in)
            {
                self.converse(&mut ws, &events_in, &events, &credits_in);
            }
            self.shared.lock_pages().remove(&self.id);
            let _ = ws.close(None);
            let _ = ws.flush();
        }
        // Wakes the reader (its read ends).
        let _ = ws.get_ref().stream.shutdown(Shutdown::Both);
        self.shared.queue.forget(2 * self.id);
        self.shared.queue.forget(2 * self.id + 1);
    }

    /// Handles every whole message the page's bytes so far hold; `false` when the page
    /// closed or the socket failed.
    fn take_messages(&self, ws: &mut WebSocket<Pipe>, events_in: &Sender<Event>) -> bool {
        loop {
            match ws.read() {
                Ok(Message::Text(text)) => {
                    if let Some(answer) = self.answer(text.as_str(), events_in)
                        && ws.send(Message::text(answer)).is_err()
                    {
                        return false;
                    }
                }
                Ok(Message::Close(_)) => {
                    let _ = ws.flush();
                    return false;
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    return true;
                }
                Err(_) => return false,
            }
        }
    }

    /// Waits for the page's requests, finished jobs and (for a running fit) progress, and
    /// answers each as it comes, until the page leaves or the server stops.
    fn converse(
        &self,
        ws: &mut WebSocket<Pipe>,
        events_in: &Sender<Event>,
        events: &Receiver<Event>,
        credits: &SyncSender<()>,
    ) {
        let mut send_ms = 0.0;
        let mut live_cursor = 0;
        let mut live_due = Instant::now();
        while !self.shared.stop.load(Ordering::Relaxed) {
            let wait = match &self.shared.showing.live {
                Some(live) => {
                    let now = Instant::now();
                    if now >= live_due {
                        live_due = now + LIVE_EVERY;
                        let (update, cursor) = live.update_since(live_cursor);
                        live_cursor = cursor;
                        let mut message =
                            serde_json::to_value(update).expect("finite numbers serialise");
                        message["type"] = "live".into();
                        if ws.send(Message::text(message.to_string())).is_err() {
                            return;
                        }
                    }
                    Some(live_due.saturating_duration_since(Instant::now()))
                }
                // Only the page, the render thread or the server's end wake an idle page.
                None => None,
            };
            let event = match wait {
                Some(wait) => events.recv_timeout(wait),
                None => events.recv().map_err(|_| RecvTimeoutError::Disconnected),
            };
            match event {
                Ok(Event::Bytes(bytes)) => {
                    ws.get_mut().inbox.extend(bytes);
                    // The reader may read one more chunk.
                    let _ = credits.try_send(());
                    if !self.take_messages(ws, events_in) {
                        return;
                    }
                }
                Ok(Event::Output(output)) => {
                    let message = encode(output, send_ms);
                    let start = Instant::now();
                    if ws.send(message).is_err() {
                        return;
                    }
                    send_ms = start.elapsed().as_secs_f64() * 1e3;
                }
                Ok(Event::Closed | Event::Stop) | Err(RecvTimeoutError::Disconnected) => return,
                Err(RecvTimeoutError::Timeout) => {}
            }
        }
    }

    /// Handles a request: a job for the render thread, or an immediate answer.
    fn answer(&self, text: &str, events_in: &Sender<Event>) -> Option<String> {
        let error = |id: Option<u64>, e: Error| {
            serde_json::json!({"type": "error", "id": id, "message": e.to_string()}).to_string()
        };
        let reply = || -> Reply {
            let events_in = events_in.clone();
            Box::new(move |output| {
                // A page that left drops its answers.
                let _ = events_in.send(Event::Output(output));
            })
        };
        let queue = &self.shared.queue;
        match parse_request(text) {
            Err(e) => Some(error(None, e)),
            Ok(Request::Frame(frame)) => match frame.camera() {
                Ok((camera, time)) => {
                    let job = Job::Frame {
                        id: frame.id,
                        camera: Box::new(camera),
                        time,
                        lossless: frame.lossless,
                    };
                    queue.submit(2 * self.id, job, reply());
                    None
                }
                Err(e) => Some(error(Some(frame.id), e)),
            },
            Ok(Request::Compare { id, view }) => {
                queue.submit(2 * self.id + 1, Job::Compare { id, view }, reply());
                None
            }
            Ok(Request::Path(path)) => Some(match path.answer() {
                Ok(answer) => answer.to_string(),
                Err(e) => error(None, e),
            }),
        }
    }
}

/// A WebSocket's reader: hands the socket's bytes to the page's thread, at most
/// [`READ_CHUNKS_WAITING`] chunks ahead of it, until the socket closes or the page's thread
/// is gone.
fn read_socket(mut stream: TcpStream, events: &Sender<Event>, credits: &Receiver<()>) {
    let mut buf = vec![0_u8; READ_CHUNK];
    while credits.recv().is_ok() {
        let n = loop {
            match stream.read(&mut buf) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Ok(0) | Err(_) => {
                    let _ = events.send(Event::Closed);
                    return;
                }
                Ok(n) => break n,
            }
        };
        if events.send(Event::Bytes(buf[..n].to_vec())).is_err() {
            return;
        }
    }
}

/// The message of a finished job: a binary frame or comparison, or a text error.
fn encode(output: Output, send_ms: f64) -> Message {
    match output {
        Output::Frame {
            id,
            image,
            time,
            alive,
            kernels,
            lossless,
            render_ms,
        } => {
            let start = Instant::now();
            let (bytes, mime) = image.encode(lossless);
            let header = serde_json::json!({
                "type": "frame", "id": id, "width": image.width, "height": image.height,
                "time": time, "alive": alive, "kernels": kernels, "render_ms": render_ms,
                "encode_ms": start.elapsed().as_secs_f64() * 1e3, "send_ms": send_ms,
            });
            Message::binary(pack(header, &[("frame", mime, &bytes)]))
        }
        Output::Compare {
            id,
            view,
            render,
            truth,
            error,
            psnr,
        } => {
            let header = serde_json::json!({
                "type": "compare", "id": id, "view": view, "psnr": psnr,
                "width": render.width, "height": render.height,
            });
            let parts: Vec<(Vec<u8>, &str)> = [&render, &truth, &error]
                .iter()
                .map(|image| image.encode(true))
                .collect();
            Message::binary(pack(
                header,
                &[
                    ("render", parts[0].1, &parts[0].0),
                    ("truth", parts[1].1, &parts[1].0),
                    ("error", parts[2].1, &parts[2].0),
                ],
            ))
        }
        Output::Failed { id, message } => Message::text(
            serde_json::json!({"type": "error", "id": id, "message": message}).to_string(),
        ),
    }
}
