//! The viewer's server: a TCP listener that answers plain `GET`s with the page's assets
//! (compiled into the binary: no CDN, works offline) and upgrades `/ws` to a WebSocket, one
//! per page. Each connection has its own thread, which reads the page's requests (a short
//! read timeout lets it also send the frames the render thread hands back, in order).
//! HTTP request heads are parsed by `httparse`, WebSockets are `tungstenite`'s.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, channel};
use std::sync::{Arc, mpsc::Sender};
use std::time::{Duration, Instant};

use tungstenite::{Message, WebSocket};

use crate::model::{Error, Result};
use crate::scenes::paths::{Lens, framing_circle, orbit, time_range};
use crate::view::Showing;
use crate::view::protocol::{Request, pack, parse_request};
use crate::view::render_thread::{Job, Output, Queue, spawn};

const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const STYLE_CSS: &str = include_str!("page/style.css");

/// Largest HTTP request head read, bytes.
const MAX_HEAD: usize = 16 * 1024;
/// Largest WebSocket message a page may send, bytes (a long keyframe list fits).
const MAX_MESSAGE: usize = 4 << 20;
/// How often a page's connection looks for finished frames while no request arrives.
const POLL: Duration = Duration::from_millis(2);
/// How often a running fit's progress is sent to its pages.
const LIVE_EVERY: Duration = Duration::from_millis(500);

/// A bound listener, not yet serving.
pub struct Server {
    listener: TcpListener,
    addr: SocketAddr,
}

impl Server {
    /// Listens on `host:port` (port 0: any free port). A port in use is a usage error
    /// naming it.
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
        Ok(Server { listener, addr })
    }

    /// The page's address.
    #[must_use]
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Serves `showing` until `stop` is set; then ends the render thread and every page's
    /// connection.
    pub fn run(self, showing: &Showing, stop: &Arc<AtomicBool>) -> Result<()> {
        self.listener
            .set_nonblocking(true)
            .map_err(|e| Error::usage(format!("cannot serve: {e}")))?;
        let queue = spawn(showing.clone());
        let hello = Arc::new(hello(showing).to_string());
        let pages = AtomicU64::new(0);
        while !stop.load(Ordering::Relaxed) {
            match self.listener.accept() {
                Ok((stream, _)) => {
                    let page = Page {
                        id: pages.fetch_add(1, Ordering::Relaxed),
                        queue: Arc::clone(&queue),
                        hello: Arc::clone(&hello),
                        showing: showing.clone(),
                        stop: Arc::clone(stop),
                    };
                    std::thread::spawn(move || page.serve(stream));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
        queue.stop();
        Ok(())
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
        &[t0, 0.5 * (t0 + t1), t1],
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
    queue: Arc<Queue>,
    hello: Arc<String>,
    showing: Showing,
    stop: Arc<AtomicBool>,
}

/// A stream that first gives back the bytes already read from it.
struct Replay {
    head: std::io::Cursor<Vec<u8>>,
    stream: TcpStream,
}

impl Read for Replay {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if (self.head.position() as usize) < self.head.get_ref().len() {
            return self.head.read(buf);
        }
        self.stream.read(buf)
    }
}

impl Write for Replay {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.stream.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// Reads a request head (up to the blank line), at most [`MAX_HEAD`] bytes.
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

/// The asset at `path`: content type and body.
fn asset(path: &str) -> Option<(&'static str, &'static str)> {
    match path.split('?').next().unwrap_or("") {
        "/" | "/index.html" => Some(("text/html; charset=utf-8", INDEX_HTML)),
        "/app.js" => Some(("text/javascript; charset=utf-8", APP_JS)),
        "/style.css" => Some(("text/css; charset=utf-8", STYLE_CSS)),
        _ => None,
    }
}

fn respond(stream: &mut TcpStream, status: &str, kind: &str, body: &[u8]) {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let _ = stream.write_all(head.as_bytes());
    let _ = stream.write_all(body);
    let _ = stream.flush();
}

impl Page {
    /// Answers one connection: an asset, or a page's WebSocket until it closes.
    fn serve(self, mut stream: TcpStream) {
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
        let _ = stream.set_write_timeout(Some(Duration::from_secs(10)));
        let Some(head) = read_head(&mut stream) else {
            return;
        };
        let mut headers = [httparse::EMPTY_HEADER; 64];
        let mut request = httparse::Request::new(&mut headers);
        if !matches!(request.parse(&head), Ok(httparse::Status::Complete(_))) {
            respond(&mut stream, "400 Bad Request", "text/plain", b"bad request");
            return;
        }
        let path = request.path.unwrap_or("").to_owned();
        let upgrade = request.headers.iter().any(|h| {
            h.name.eq_ignore_ascii_case("upgrade")
                && String::from_utf8_lossy(h.value).eq_ignore_ascii_case("websocket")
        });
        if request.method != Some("GET") {
            respond(
                &mut stream,
                "405 Method Not Allowed",
                "text/plain",
                b"GET only",
            );
        } else if path == "/ws" && upgrade {
            self.websocket(head, stream);
        } else if path.starts_with("/first.jpg") {
            match self.first_frame(&path) {
                Some(jpeg) => respond(&mut stream, "200 OK", "image/jpeg", &jpeg),
                None => respond(
                    &mut stream,
                    "503 Service Unavailable",
                    "text/plain",
                    b"no frame",
                ),
            }
        } else if let Some((kind, body)) = asset(&path) {
            respond(&mut stream, "200 OK", kind, body.as_bytes());
        } else {
            respond(&mut stream, "404 Not Found", "text/plain", b"not found");
        }
    }

    /// The first frame as a JPEG, `GET /first.jpg?width=W&height=H` (sides clamped to
    /// [`crate::view::MAX_SIDE`]): the start view at the start time. The page loads it as an
    /// image, so the page's load (and a screenshot taken then) waits for a drawn scene.
    fn first_frame(&self, path: &str) -> Option<Vec<u8>> {
        let query = path.split_once('?').map_or("", |(_, q)| q);
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
        let camera = crate::model::Camera::from_opengl_camera_to_world(
            width,
            height,
            crate::model::Camera::centred_intrinsics(width, height, START_FOV.to_radians()),
            start_view(&self.showing).0?,
        )
        .ok()?;
        let (reply, frames) = channel();
        let job = Job::Frame {
            id: 0,
            camera,
            time: time_range(&self.showing.scene)[0],
            lossless: false,
        };
        self.queue.submit(2 * self.id, job, reply);
        match frames.recv_timeout(Duration::from_secs(60)).ok()? {
            Output::Frame { image, .. } => Some(image.encode(false).0),
            _ => None,
        }
    }

    /// The WebSocket of one page: requests in, frames and answers out.
    fn websocket(self, head: Vec<u8>, stream: TcpStream) {
        let replay = Replay {
            head: std::io::Cursor::new(head),
            stream,
        };
        let config = tungstenite::protocol::WebSocketConfig::default()
            .max_message_size(Some(MAX_MESSAGE))
            .max_frame_size(Some(MAX_MESSAGE));
        let Ok(mut ws) = tungstenite::accept_with_config(replay, Some(config)) else {
            return;
        };
        let _ = ws.get_ref().stream.set_read_timeout(Some(POLL));
        let (reply, frames) = channel();
        if ws.send(Message::text(self.hello.as_str())).is_ok() {
            self.converse(&mut ws, &reply, &frames);
        }
        self.queue.forget(2 * self.id);
        self.queue.forget(2 * self.id + 1);
    }

    /// Reads requests and sends what is ready until the page leaves or the server stops.
    fn converse(
        &self,
        ws: &mut WebSocket<Replay>,
        reply: &Sender<Output>,
        frames: &Receiver<Output>,
    ) {
        let mut send_ms = 0.0;
        let mut live_cursor = 0;
        let mut live_at = Instant::now() - LIVE_EVERY;
        while !self.stop.load(Ordering::Relaxed) {
            match ws.read() {
                Ok(Message::Text(text)) => {
                    if let Some(answer) = self.answer(text.as_str(), reply)
                        && ws.send(Message::text(answer)).is_err()
                    {
                        return;
                    }
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => return,
            }
            while let Ok(output) = frames.try_recv() {
                let message = encode(output, send_ms);
                let start = Instant::now();
                if ws.send(message).is_err() {
                    return;
                }
                send_ms = start.elapsed().as_secs_f64() * 1e3;
            }
            if let Some(live) = &self.showing.live
                && live_at.elapsed() >= LIVE_EVERY
            {
                live_at = Instant::now();
                let (update, cursor) = live.update_since(live_cursor);
                live_cursor = cursor;
                let mut message = serde_json::to_value(update).expect("finite numbers serialise");
                message["type"] = "live".into();
                if ws.send(Message::text(message.to_string())).is_err() {
                    return;
                }
            }
        }
        let _ = ws.close(None);
        let _ = ws.flush();
    }

    /// Handles a request: a job for the render thread, or an immediate answer.
    fn answer(&self, text: &str, reply: &Sender<Output>) -> Option<String> {
        let error = |id: Option<u64>, e: Error| {
            serde_json::json!({"type": "error", "id": id, "message": e.to_string()}).to_string()
        };
        match parse_request(text) {
            Err(e) => Some(error(None, e)),
            Ok(Request::Frame(frame)) => match frame.camera() {
                Ok((camera, time)) => {
                    let job = Job::Frame {
                        id: frame.id,
                        camera,
                        time,
                        lossless: frame.lossless,
                    };
                    self.queue.submit(2 * self.id, job, reply.clone());
                    None
                }
                Err(e) => Some(error(Some(frame.id), e)),
            },
            Ok(Request::Compare { id, view }) => {
                self.queue
                    .submit(2 * self.id + 1, Job::Compare { id, view }, reply.clone());
                None
            }
            Ok(Request::Path(path)) => Some(match path.answer() {
                Ok(answer) => answer.to_string(),
                Err(e) => error(None, e),
            }),
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
