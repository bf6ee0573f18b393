#version 330
// The scene pass's vertex stage: world-space vertices to clip space. With POSED (`gl_posed`):
// model-frame vertices, each moved into the world by its joint's transform, read from `joints`.
// Uniforms: mvp (view-projection), shadow_matrix (world to the sun's shadow-map space);
// with POSED, joints (per joint four texels: the rows of [R | t], then the model's headlight
// and tail-light emission).
uniform mat4 mvp;
uniform mat4 shadow_matrix;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_colour;
in float in_body;
in float in_emission;
in float in_material;
out vec3 world_position;
out vec3 normal;
out vec3 colour;
out float eye_depth;
out vec4 shadow_position;
flat out float body;
flat out float emission;
flat out int material;
#ifdef POSED
#include "posed.glsl"
#endif
void main() {
#ifdef POSED
    PosedVertex posed = posed_vertex(in_position, in_normal, in_emission);
    vec3 position = posed.position;
    vec3 vertex_normal = posed.normal;
    emission = posed.emission;
#else
    vec3 position = in_position;
    vec3 vertex_normal = in_normal;
    emission = in_emission;
#endif
    gl_Position = mvp * vec4(position, 1.0);
    eye_depth = gl_Position.w;  // a perspective projection's w: the depth along the view axis
    world_position = position;
    // a little towards the normal, so that a surface does not shadow itself (normal offset)
    shadow_position = shadow_matrix * vec4(position + 0.04 * vertex_normal, 1.0);
    normal = vertex_normal;
    colour = in_colour;
    body = in_body;
    material = int(in_material + 0.5);
}
