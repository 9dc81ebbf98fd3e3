//! The wgpu path of the microscope scene: a render pipeline with the small
//! WGSL shader `scene.wgsl`, drawn through an `egui_wgpu` paint callback
//! (one full-rect triangle, the uniform block of [`super::scene::uniforms`]).
//!
//! [`install`] creates the pipeline inside a validation error scope; any
//! failure (no wgpu render state — e.g. the glow renderer —, a shader or
//! pipeline error) is reported and the scene falls back to the egui painter.

use super::scene::{SceneFrame, UNIFORM_BYTES, uniforms};
use eframe::egui_wgpu::{self, CallbackResources, CallbackTrait, RenderState, wgpu};
use std::future::Future;
use std::num::NonZeroU64;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

/// The shader source.
pub const SHADER: &str = include_str!("scene.wgsl");

/// GPU objects kept in egui_wgpu's callback resources.
#[derive(Debug)]
struct SceneResources {
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
    uniforms: wgpu::Buffer,
}

/// Poll a future that the native wgpu backends complete at once.
fn ready_now<F: Future>(f: F) -> Option<F::Output> {
    let mut f = pin!(f);
    let mut cx = Context::from_waker(Waker::noop());
    match f.as_mut().poll(&mut cx) {
        Poll::Ready(v) => Some(v),
        Poll::Pending => None,
    }
}

/// Build the pipeline from `shader` and register it with the renderer.
pub fn install_with_shader(rs: &RenderState, shader: &str) -> Result<(), String> {
    let device = &rs.device;
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("kilotouch scene"),
        source: wgpu::ShaderSource::Wgsl(shader.into()),
    });
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("kilotouch scene"),
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: NonZeroU64::new(UNIFORM_BYTES as u64),
            },
            count: None,
        }],
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("kilotouch scene"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("kilotouch scene"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(rs.target_format.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("kilotouch scene uniforms"),
        size: UNIFORM_BYTES as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("kilotouch scene"),
        layout: &layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: buffer.as_entire_binding(),
        }],
    });
    if let Some(Some(err)) = ready_now(scope.pop()) {
        return Err(format!("scene pipeline: {err}"));
    }
    rs.renderer
        .write()
        .callback_resources
        .insert(SceneResources {
            pipeline,
            bind_group,
            uniforms: buffer,
        });
    Ok(())
}

/// Build the scene pipeline and register it with the renderer.
pub fn install(rs: &RenderState) -> Result<(), String> {
    install_with_shader(rs, SHADER)
}

/// One frame's paint callback.
#[derive(Debug)]
pub struct SceneCallback {
    data: [u8; UNIFORM_BYTES],
}

impl SceneCallback {
    /// The callback painting `frame` into its view rectangle.
    pub fn paint_callback(frame: &SceneFrame) -> egui::PaintCallback {
        egui_wgpu::Callback::new_paint_callback(
            frame.view.rect,
            SceneCallback {
                data: uniforms(frame),
            },
        )
    }
}

impl CallbackTrait for SceneCallback {
    fn prepare(
        &self,
        _device: &wgpu::Device,
        queue: &wgpu::Queue,
        _screen: &egui_wgpu::ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        if let Some(r) = resources.get::<SceneResources>() {
            queue.write_buffer(&r.uniforms, 0, &self.data);
        }
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        render_pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        if let Some(r) = resources.get::<SceneResources>() {
            render_pass.set_pipeline(&r.pipeline);
            render_pass.set_bind_group(0, &r.bind_group, &[]);
            render_pass.draw(0..3, 0..1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use eframe::wgpu::naga;

    #[test]
    fn shader_parses_and_validates_and_matches_the_uniform_size() {
        let module = naga::front::wgsl::parse_str(SHADER).expect("WGSL parses");
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::empty(),
        )
        .validate(&module)
        .expect("WGSL validates");
        // The uniform struct's size equals what the Rust side writes.
        let u = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("Uniforms"))
            .expect("Uniforms struct");
        assert_eq!(u.1.inner.size(module.to_ctx()) as usize, UNIFORM_BYTES);
        for entry in ["vs_main", "fs_main"] {
            assert!(module.entry_points.iter().any(|e| e.name == entry));
        }
    }
}
