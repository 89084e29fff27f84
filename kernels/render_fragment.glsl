#version 330 core
// Two-sided Lambert shading with a directional light (rigslim.render.lambert):
//   rgb = c * (ambient + (1 - ambient) * |n . l|),  n = normalize(interpolated normal).
in vec3 v_normal;
in vec3 v_color;

uniform vec3 u_light;     // unit direction towards the light, world space
uniform float u_ambient;  // in [0, 1]

out vec4 frag_color;

void main() {
    float len = length(v_normal);
    vec3 n = len > 0.0 ? v_normal / len : vec3(0.0);
    float lambert = abs(dot(n, u_light));
    frag_color = vec4(v_color * (u_ambient + (1.0 - u_ambient) * lambert), 1.0);
}
