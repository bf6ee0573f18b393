#version 330
// The sun's shadow map: depth only, seen from the sun; with POSED, model-frame vertices moved
// by their joints (`posed.glsl`).
// Uniforms: shadow_matrix (world to the shadow map's clip space); with POSED, joints.
uniform mat4 shadow_matrix;
in vec3 in_position;
#ifdef POSED
#include "posed.glsl"
#endif
void main() {
#ifdef POSED
    vec3 position = posed_vertex(in_position, vec3(0.0), 0.0).position;
#else
    vec3 position = in_position;
#endif
    gl_Position = shadow_matrix * vec4(position, 1.0);
}
