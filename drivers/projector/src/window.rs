//! The window projector: winit owns the window on a dedicated thread (its event loop), wgpu
//! draws each slide as a full-screen triangle whose fragment shader copies the slide's texel
//! at the fragment's pixel (`textureLoad`, no sampler), so every projector pixel gets exactly
//! its 8-bit value.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

use ris_core::pattern::CodeLayout;
use ris_drivers::clock::now_ns;
use ris_drivers::{DriverError, ErrorKind, Projector, ProjectorInfo, Result, Shown, Slide};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop, EventLoopProxy};
use winit::platform::x11::{EventLoopBuilderExtX11, WindowAttributesExtX11};
use winit::window::{Fullscreen, Window, WindowId};

/// How long opening the window and the GPU device may take.
const OPEN_TIMEOUT: Duration = Duration::from_secs(30);
/// How long one command (upload, present) may take.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(10);
/// How long closing a window (its GPU state released) may take.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(5);

const SHADER: &str = r"
@group(0) @binding(0) var slide: texture_2d<f32>;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the viewport.
    let x = f32(i32(i & 1u) * 4 - 1);
    let y = f32(i32(i >> 1u) * 4 - 1);
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let v = textureLoad(slide, vec2<i32>(p.xy), 0).r;
    return vec4<f32>(v, v, v, 1.0);
}
";

/// Where and how big the projector window is.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    /// Projector width, pixels (the monitor's mode must match).
    pub width: u32,
    /// Projector height, pixels.
    pub height: u32,
    /// Monitor index, in the order the display server lists them.
    pub monitor: usize,
}

enum Command {
    Open(u64, WindowOptions, mpsc::Sender<Result<()>>),
    Load(u64, Vec<Vec<u8>>, mpsc::Sender<Result<()>>),
    Show(u64, usize, mpsc::Sender<Result<u64>>),
    Close(u64, mpsc::Sender<Result<()>>),
}

/// A projector that is a borderless full-screen window.
pub struct WindowProjector {
    info: ProjectorInfo,
    layout: CodeLayout,
    key: u64,
    proxy: EventLoopProxy<Command>,
    slides: usize,
    sequence: u64,
}

fn error(kind: ErrorKind, device: &str, message: impl Into<String>) -> DriverError {
    DriverError::new(kind, device, message)
}

/// The error of every projector once the X connection has broken.
fn lost(device: &str) -> DriverError {
    error(
        ErrorKind::Disconnected,
        device,
        "the connection to the X server broke; projector windows come back when risd restarts",
    )
}

/// The process's display thread: winit allows one event loop per process, so every projector
/// window of a cell lives on this one thread, started by the first window opened.
fn display(device: &str) -> Result<EventLoopProxy<Command>> {
    static DISPLAY: Mutex<Option<std::result::Result<EventLoopProxy<Command>, String>>> =
        Mutex::new(None);
    let mut slot = DISPLAY.lock().unwrap_or_else(|e| e.into_inner());
    if crate::connection::lost() {
        return Err(lost(device));
    }
    if let Some(started) = slot.as_ref() {
        return started
            .clone()
            .map_err(|e| error(ErrorKind::Unsupported, device, e));
    }
    if let Err(e) = crate::connection::guard() {
        let e = format!("no display: {e}");
        *slot = Some(Err(e.clone()));
        return Err(error(ErrorKind::Unsupported, device, e));
    }
    let (proxy_tx, proxy_rx) = mpsc::channel();
    let spawned = std::thread::Builder::new()
        .name("projector-display".into())
        .spawn(move || {
            let event_loop = match EventLoop::<Command>::with_user_event()
                .with_any_thread(true)
                .build()
            {
                Ok(l) => l,
                Err(e) => {
                    let _ = proxy_tx.send(Err(format!(
                        "no display (is DISPLAY set and an X server running?): {e}"
                    )));
                    return;
                }
            };
            event_loop.set_control_flow(ControlFlow::Wait);
            let _ = proxy_tx.send(Ok(event_loop.create_proxy()));
            let mut app = App {
                windows: HashMap::new(),
            };
            if let Err(e) = event_loop.run_app(&mut app) {
                tracing::warn!(error = %e, "projector event loop ended with an error");
            }
        });
    let started = match spawned {
        Ok(_) => proxy_rx
            .recv_timeout(OPEN_TIMEOUT)
            .unwrap_or_else(|_| Err("the display thread did not start".into())),
        Err(e) => Err(format!("spawning the display thread: {e}")),
    };
    *slot = Some(started.clone());
    started.map_err(|e| error(ErrorKind::Unsupported, device, e))
}

impl WindowProjector {
    /// Open the window on `options.monitor` of the display (X11 `DISPLAY`), set up the GPU
    /// and show black.
    pub fn open(options: &WindowOptions) -> Result<WindowProjector> {
        static NEXT: AtomicU64 = AtomicU64::new(1);
        let id = format!("window:{}", options.monitor);
        if options.width == 0 || options.height == 0 {
            return Err(error(
                ErrorKind::InvalidArgument,
                &id,
                format!("projector size {}x{}", options.width, options.height),
            ));
        }
        let proxy = display(&id)?;
        let mut projector = WindowProjector {
            info: ProjectorInfo {
                id,
                width: options.width,
                height: options.height,
            },
            layout: CodeLayout::new(options.width, options.height),
            key: NEXT.fetch_add(1, Ordering::Relaxed),
            proxy,
            slides: 0,
            sequence: 0,
        };
        let (key, opts) = (projector.key, options.clone());
        if let Err(e) = projector.call(
            |tx| Command::Open(key, opts, tx),
            "opening the window",
            OPEN_TIMEOUT,
        ) {
            // Nothing to close: the display thread keeps no half-open window.
            projector.key = 0;
            return Err(e);
        }
        Ok(projector)
    }

    fn call<T>(
        &self,
        make: impl FnOnce(mpsc::Sender<Result<T>>) -> Command,
        what: &str,
        timeout: Duration,
    ) -> Result<T> {
        if crate::connection::lost() {
            return Err(lost(&self.info.id));
        }
        let (tx, rx) = mpsc::channel();
        self.proxy.send_event(make(tx)).map_err(|_| {
            error(
                ErrorKind::Disconnected,
                &self.info.id,
                "the display thread has ended",
            )
        })?;
        // Waited in slices, so that a broken X connection (which parks the display thread)
        // fails the command at once rather than after the timeout.
        let deadline = std::time::Instant::now() + timeout;
        loop {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(result) => return result,
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(error(
                        ErrorKind::Disconnected,
                        &self.info.id,
                        format!("the display thread dropped the request ({what})"),
                    ))
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
            }
            if crate::connection::lost() {
                return Err(lost(&self.info.id));
            }
            if std::time::Instant::now() >= deadline {
                return Err(error(
                    ErrorKind::Timeout,
                    &self.info.id,
                    format!("{what} did not finish within {} s", timeout.as_secs()),
                ));
            }
        }
    }
}

impl Projector for WindowProjector {
    fn info(&self) -> &ProjectorInfo {
        &self.info
    }

    fn load(&mut self, slides: &[Slide]) -> Result<()> {
        let images: Vec<Vec<u8>> = slides.iter().map(|s| s.render(&self.layout)).collect();
        let n = images.len();
        let key = self.key;
        self.call(
            |tx| Command::Load(key, images, tx),
            "uploading the slides",
            COMMAND_TIMEOUT,
        )?;
        self.slides = n;
        Ok(())
    }

    fn show(&mut self, slot: usize) -> Result<Shown> {
        if slot >= self.slides {
            return Err(error(
                ErrorKind::InvalidArgument,
                &self.info.id,
                format!("slide {slot} of {} loaded", self.slides),
            ));
        }
        let key = self.key;
        let presented_ns = self.call(
            |tx| Command::Show(key, slot, tx),
            "presenting",
            COMMAND_TIMEOUT,
        )?;
        self.sequence += 1;
        Ok(Shown {
            slot,
            sequence: self.sequence,
            presented_ns,
        })
    }
}

impl Drop for WindowProjector {
    /// Closes the window and waits until its GPU state is gone: a process that exits right after
    /// would otherwise run its exit handlers while the display thread tears down the Vulkan
    /// driver, which unloads the library those handlers are in (a crash at exit under load).
    fn drop(&mut self) {
        if self.key != 0 {
            let key = self.key;
            if let Err(e) = self.call(
                |tx| Command::Close(key, tx),
                "closing the window",
                CLOSE_TIMEOUT,
            ) {
                tracing::warn!(error = %e, "projector window not closed");
            }
        }
    }
}

/// Every projector window of the process, on the display thread.
struct App {
    windows: HashMap<u64, Projection>,
}

/// One projector window and its GPU state.
struct Projection {
    options: WindowOptions,
    device: String,
    window: Option<Arc<Window>>,
    gpu: Option<Gpu>,
    current: Option<usize>,
}

struct Gpu {
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    /// One bind group (and its texture) per loaded slide.
    slides: Vec<(wgpu::Texture, wgpu::BindGroup)>,
}

impl Projection {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let (w, h) = (self.options.width, self.options.height);
        // The monitor as RandR lists it (virtual monitors included); winit only knows CRTCs.
        let screen = crate::screen::Screen::connect(None)?;
        let target = screen.monitor(self.options.monitor).map_err(|e| {
            error(
                ErrorKind::InvalidArgument,
                &self.device,
                format!("projector monitor {}: {}", self.options.monitor, e.message),
            )
        })?;
        drop(screen);
        if (u32::from(target.width), u32::from(target.height)) != (w, h) {
            return Err(error(
                ErrorKind::InvalidArgument,
                &self.device,
                format!(
                    "monitor {} ({}) is {}x{}, the projector is {w}x{h}: set the monitor's mode to the projector's native resolution",
                    self.options.monitor, target.name, target.width, target.height
                ),
            ));
        }
        let (x, y) = (i32::from(target.x), i32::from(target.y));
        // A CRTC with exactly this rectangle is a real output: full screen on it, so a window
        // manager keeps it there. Otherwise (a virtual monitor, part of a larger output) the
        // window is placed on the rectangle and bypasses the window manager.
        let crtc = event_loop.available_monitors().find(|m| {
            let (p, s) = (m.position(), m.size());
            (p.x, p.y, s.width, s.height) == (x, y, w, h)
        });
        let mut attrs = Window::default_attributes()
            .with_title("RIS projector")
            .with_decorations(false)
            .with_resizable(false)
            .with_inner_size(PhysicalSize::new(w, h))
            .with_position(PhysicalPosition::new(x, y));
        attrs = match crtc {
            Some(m) => attrs.with_fullscreen(Some(Fullscreen::Borderless(Some(m)))),
            None => attrs.with_override_redirect(true),
        };
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| {
            error(
                ErrorKind::Failed,
                &self.device,
                format!("creating the window: {e}"),
            )
        })?);
        window.set_cursor_visible(false);
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(
                Box::new(event_loop.owned_display_handle()),
            ));
        let surface = instance.create_surface(window.clone()).map_err(|e| {
            error(
                ErrorKind::Failed,
                &self.device,
                format!("creating the surface: {e}"),
            )
        })?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))
        .map_err(|e| {
            error(
                ErrorKind::Unsupported,
                &self.device,
                format!("no GPU adapter can present to this window: {e}"),
            )
        })?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("projector"),
            required_limits: wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits()),
            ..Default::default()
        }))
        .map_err(|e| {
            error(
                ErrorKind::Failed,
                &self.device,
                format!("opening {}: {e}", info.name),
            )
        })?;
        let caps = surface.get_capabilities(&adapter);
        // A non-sRGB format: the 8-bit values must reach the screen unchanged.
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| {
                matches!(
                    f,
                    wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Rgba8Unorm
                )
            })
            .ok_or_else(|| {
                error(
                    ErrorKind::Unsupported,
                    &self.device,
                    format!("no linear 8-bit surface format among {:?}", caps.formats),
                )
            })?;
        let mut config = surface.get_default_config(&adapter, w, h).ok_or_else(|| {
            error(
                ErrorKind::Unsupported,
                &self.device,
                "the surface cannot be configured",
            )
        })?;
        config.format = format;
        config.view_formats = vec![];
        config.present_mode = wgpu::PresentMode::Fifo;
        config.desired_maximum_frame_latency = 1;
        surface.configure(&device, &config);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("slide"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("slide"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("slide"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("slide"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        tracing::info!(
            adapter = %info.name,
            backend = ?info.backend,
            ?format,
            width = w,
            height = h,
            "projector window open"
        );
        self.window = Some(window);
        self.gpu = Some(Gpu {
            surface,
            device,
            queue,
            config,
            pipeline,
            layout,
            slides: Vec::new(),
        });
        // Black until the first slide.
        self.load(vec![vec![0; (w * h) as usize]])?;
        self.present(0)?;
        Ok(())
    }

    fn gpu(&mut self) -> Result<&mut Gpu> {
        let device = self.device.clone();
        self.gpu
            .as_mut()
            .ok_or_else(|| error(ErrorKind::Failed, &device, "the GPU is not set up"))
    }

    fn load(&mut self, images: Vec<Vec<u8>>) -> Result<()> {
        let (w, h) = (self.options.width, self.options.height);
        let device = self.device.clone();
        let gpu = self.gpu()?;
        let mut slides = Vec::with_capacity(images.len());
        for (i, px) in images.iter().enumerate() {
            if px.len() != (w * h) as usize {
                return Err(error(
                    ErrorKind::InvalidArgument,
                    &device,
                    format!("slide {i} has {} pixels, expected {w}x{h}", px.len()),
                ));
            }
            let size = wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            };
            let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("slide"),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                px,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(w),
                    rows_per_image: Some(h),
                },
                size,
            );
            let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
            let group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("slide"),
                layout: &gpu.layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                }],
            });
            slides.push((texture, group));
        }
        gpu.queue.submit([]);
        gpu.slides = slides;
        self.current = None;
        Ok(())
    }

    /// Draw slide `slot`, present it and wait until the GPU finished; the time after.
    fn present(&mut self, slot: usize) -> Result<u64> {
        let device = self.device.clone();
        let gpu = self.gpu()?;
        let mut frame = None;
        for _ in 0..3 {
            match gpu.surface.get_current_texture() {
                wgpu::CurrentSurfaceTexture::Success(t)
                | wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                    frame = Some(t);
                    break;
                }
                wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                    gpu.surface.configure(&gpu.device, &gpu.config);
                }
                other => {
                    return Err(error(
                        ErrorKind::Failed,
                        &device,
                        format!("no surface texture: {other:?}"),
                    ))
                }
            }
        }
        let frame = frame.ok_or_else(|| {
            error(
                ErrorKind::Failed,
                &device,
                "the surface stayed outdated after reconfiguring",
            )
        })?;
        let view = frame
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("show"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("show"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&gpu.pipeline);
            pass.set_bind_group(0, &gpu.slides[slot].1, &[]);
            pass.draw(0..3, 0..1);
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.queue.present(frame);
        gpu.device
            .poll(wgpu::PollType::Wait {
                submission_index: None,
                timeout: Some(COMMAND_TIMEOUT),
            })
            .map_err(|e| error(ErrorKind::Timeout, &device, format!("presenting: {e}")))?;
        self.current = Some(slot);
        Ok(now_ns())
    }
}

impl ApplicationHandler<Command> for App {
    fn resumed(&mut self, _: &ActiveEventLoop) {}

    fn user_event(&mut self, event_loop: &ActiveEventLoop, command: Command) {
        let missing = |key: u64| {
            error(
                ErrorKind::Disconnected,
                "window",
                format!("no window {key}"),
            )
        };
        match command {
            Command::Open(key, options, tx) => {
                let mut p = Projection {
                    device: format!("window:{}", options.monitor),
                    options,
                    window: None,
                    gpu: None,
                    current: None,
                };
                let result = p.open(event_loop);
                if result.is_ok() {
                    self.windows.insert(key, p);
                }
                let _ = tx.send(result);
            }
            Command::Load(key, images, tx) => {
                let _ = tx.send(match self.windows.get_mut(&key) {
                    Some(p) => p.load(images),
                    None => Err(missing(key)),
                });
            }
            Command::Show(key, slot, tx) => {
                let _ = tx.send(match self.windows.get_mut(&key) {
                    Some(p) => p.present(slot),
                    None => Err(missing(key)),
                });
            }
            Command::Close(key, tx) => {
                drop(self.windows.remove(&key));
                let _ = tx.send(Ok(()));
            }
        }
    }

    fn window_event(&mut self, _: &ActiveEventLoop, id: WindowId, event: WindowEvent) {
        let Some(p) = self
            .windows
            .values_mut()
            .find(|p| p.window.as_ref().is_some_and(|w| w.id() == id))
        else {
            return;
        };
        match event {
            // Exposed again (another window covered it): draw the current slide once more.
            WindowEvent::RedrawRequested => {
                if let Some(slot) = p.current {
                    if let Err(e) = p.present(slot) {
                        tracing::warn!(error = %e, "projector redraw failed");
                    }
                }
            }
            WindowEvent::CloseRequested => {
                tracing::warn!("the projector window cannot be closed while risd uses it");
            }
            _ => {}
        }
    }
}
