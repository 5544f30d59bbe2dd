//! The device, made once: adapter selection (a real GPU before a software one, or the one named
//! by `--adapter`), the device with the adapter's own limits, and error capture (wgpu's default
//! handler panics; ours records the message and the engine returns a [`GpuError`]).

use std::sync::{Arc, Mutex};

use super::GpuError;

/// A wgpu device and queue with what was learned about the adapter.
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The chosen adapter.
    pub info: wgpu::AdapterInfo,
    /// The device's limits (the adapter's, not the WebGPU defaults).
    pub limits: wgpu::Limits,
    /// The optional features the device was created with (`SHADER_F64`, `PIPELINE_CACHE` where
    /// available).
    pub features: wgpu::Features,
    errors: Arc<Mutex<Vec<String>>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.describe())
            .finish()
    }
}

/// Preference order: discrete, integrated, virtual, other, software.
fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// Every Vulkan adapter as `(name, type)`, for messages and `--adapter`.
pub fn list_adapters() -> Vec<(String, wgpu::DeviceType)> {
    let instance = instance();
    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN))
        .iter()
        .map(|a| {
            let i = a.get_info();
            (i.name, i.device_type)
        })
        .collect()
}

fn instance() -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    })
}

impl GpuContext {
    /// The preferred adapter: a real GPU over a software one.
    pub fn new() -> Result<GpuContext, GpuError> {
        GpuContext::with_adapter(None)
    }

    /// The adapter whose name contains `name` (case-insensitive), or the preferred one.
    pub fn with_adapter(name: Option<&str>) -> Result<GpuContext, GpuError> {
        let instance = instance();
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
        let available: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
        let adapter = adapters
            .into_iter()
            .filter(|a| match name {
                Some(n) => a.get_info().name.to_lowercase().contains(&n.to_lowercase()),
                None => true,
            })
            .min_by_key(|a| rank(a.get_info().device_type))
            .ok_or_else(|| GpuError::NoAdapter {
                requested: name.map(str::to_string),
                available: available.clone(),
            })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        // f64 shaders (`--f64`) and pipeline caches (`disk_cache`) where the adapter has them;
        // nothing else is optional.
        let features =
            adapter.features() & (wgpu::Features::SHADER_F64 | wgpu::Features::PIPELINE_CACHE);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("cbfreach"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device(format!("{}: {e}", info.name)))?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        Ok(GpuContext {
            device,
            queue,
            info,
            limits,
            features,
            errors,
        })
    }

    /// `name (type, driver)`, as printed by the CLI.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {} {})",
            self.info.name, self.info.device_type, self.info.driver, self.info.driver_info
        )
    }

    /// Whether the device runs f64 shaders (`wgpu::Features::SHADER_F64`).
    pub fn has_f64(&self) -> bool {
        self.features.contains(wgpu::Features::SHADER_F64)
    }

    /// Whether the adapter is a software rasteriser (lavapipe, SwiftShader).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The first error the device reported since the last call, if any.
    pub fn take_error(&self) -> Result<(), GpuError> {
        let mut v = self
            .errors
            .lock()
            .map_err(|_| GpuError::Device("error sink poisoned".into()))?;
        if v.is_empty() {
            Ok(())
        } else {
            let all = v.join("; ");
            v.clear();
            Err(GpuError::Device(all))
        }
    }

    /// Waits until the queue is idle.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Device(e.to_string()))?;
        self.take_error()
    }
}
